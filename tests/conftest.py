"""Session set-up shared by every test folder."""

import pytest


@pytest.fixture(scope="session", autouse=True)
def belt_table_built():
    """Build the simulated CVT's belt-model efficiency table once, before any test.

    The simulated rig reads it from the belt model's disk cache; on a fresh
    machine the first rig would otherwise build it (about 60 s) inside whatever
    test happens to come first, and a UI test that checks *when* the belt
    solver gets imported would see the simulator's import instead of the UI's.
    Parallel workers share the cache; a lock file makes one of them build.
    """
    from dyno.sim.belt_table import belt_table
    from dyno.sim.physics import DEFAULT_TUNE, _load_tune

    belt_table(None, _load_tune(DEFAULT_TUNE))  # the default sim's table: at the stock tune's clamp
    yield


@pytest.fixture(scope="session", autouse=True)
def runs_library_dir(tmp_path_factory):
    """Runs and the run library go to a temporary directory, never the checkout's runs/.

    ``dyno run`` indexes every run in ``$DYNO_RUNS_DIR`` (docs/library.md); commands
    started as subprocesses inherit this.
    """
    import os

    old = os.environ.get("DYNO_RUNS_DIR")
    os.environ["DYNO_RUNS_DIR"] = str(tmp_path_factory.mktemp("runs-library"))
    yield
    if old is None:
        os.environ.pop("DYNO_RUNS_DIR", None)
    else:
        os.environ["DYNO_RUNS_DIR"] = old
