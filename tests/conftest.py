"""Session set-up shared by every test folder."""

import pytest


@pytest.fixture(scope="session", autouse=True)
def belt_table_built():
    """Build the simulated CVT's belt-model efficiency table once, before any test.

    The simulated rig reads it from the belt model's disk cache; on a fresh
    machine the first rig would otherwise build it (about 20 s) inside whatever
    test happens to come first, and a UI test that checks *when* the belt
    solver gets imported would see the simulator's import instead of the UI's.
    Parallel workers share the cache; a lock file makes one of them build.
    """
    from dyno.sim.belt_table import belt_table

    belt_table()
    yield
