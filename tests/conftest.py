"""Session set-up shared by every test folder: the simulated rig's belt table built before any test waits on
it, runs in a temporary library, a real terminal per test, and a check that nothing the suite started outlives it."""

import os
import uuid

import pytest

from tests import processes


def pytest_configure(config):
    """Mark this run: every process a test starts inherits the mark (xdist's workers too, started after this),
    and the belt table's cache, so a program started with a fresh HOME reads the table the session built."""
    if not os.environ.get(processes.SUITE_MARK):
        os.environ[processes.SUITE_MARK] = uuid.uuid4().hex
    if not os.environ.get("DYNO_MODEL_CACHE"):
        from dyno.model.cache_keys import default_cache_dir

        os.environ["DYNO_MODEL_CACHE"] = str(default_cache_dir())


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session, exitstatus):
    """Fail the run when a process the suite started is still alive at its end (then end it).

    Only the controlling process looks (with xdist, its workers are its children and are left out); a stray gets
    a few seconds to finish its own shutdown first."""
    if hasattr(session.config, "workerinput"):
        return
    me = os.getpid()
    mark = os.environ.get(processes.SUITE_MARK, "")

    def strays() -> list[int]:
        workers = set(processes.children_of(me))
        return [p for p in processes.marked(processes.SUITE_MARK, mark) if p not in workers]

    left = processes.wait_gone(strays, timeout_s=15.0, poll_s=0.2)
    if left:
        what = processes.describe(left)
        processes.kill(left)
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        line = f"processes started by the tests still alive at the end of the run (now killed): {what}"
        if reporter is not None:
            reporter.write_line(line, red=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


@pytest.fixture(autouse=True)
def no_process_outlives_its_test():
    """Whatever a test started (directly or through its fixtures) ends with it: after the test's own teardown, a
    process it left gets a few seconds, then SIGKILL, and the test errors naming it.  (Processes of wider-scoped
    fixtures, set up before this, and what they start are not the test's; a tmux server is detached, and the ``terminal`` fixture
    ends it.)"""
    me = os.getpid()
    before = processes.descendants(me)
    yield
    left = processes.wait_gone(lambda: sorted(processes.descendants(me, before) - before), timeout_s=10.0,
                                  poll_s=0.1)
    if left:
        what = processes.describe(left)
        processes.kill(left)
        pytest.fail(f"the test left processes running (now killed): {what}", pytrace=False)


@pytest.fixture
def terminal():
    """``terminal(command, size=(80, 24), cwd=None, env=None)``: a :class:`tests.screens.Terminal` of the
    test's own; every one is closed, its processes ended, whether the test passed or failed."""
    from tests.screens import Terminal

    opened: list[Terminal] = []

    def open_terminal(command: str, **kwargs) -> Terminal:
        t = Terminal(command, **kwargs)
        opened.append(t)
        return t

    yield open_terminal
    killed = []
    for t in opened:
        t.close()
        killed += [f"`{t.command}`: {t.killed}"] if t.killed else []
    if killed:  # a program that outlives its terminal's hang-up by 20 s would outlive a dropped SSH link too
        pytest.fail("still running 20 s after its terminal closed (now killed): " + "; ".join(killed), pytrace=False)


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
    from dyno.sim.rig_params import DEFAULT_TUNE, load_sim_tune

    belt_table(None, load_sim_tune(DEFAULT_TUNE))  # the default sim's table: at the stock tune's clamp
    yield


@pytest.fixture(scope="session", autouse=True)
def runs_library_dir(tmp_path_factory):
    """Runs and the run library, and the state directory, go to temporary directories, never the user's.

    ``dyno run`` indexes every run in ``$DYNO_RUNS_DIR`` (docs/library.md); commands
    started as subprocesses inherit this.
    """
    import os

    old = {name: os.environ.get(name) for name in ("DYNO_RUNS_DIR", "DYNO_STATE_DIR")}
    os.environ["DYNO_RUNS_DIR"] = str(tmp_path_factory.mktemp("runs-library"))
    # what dyno keeps between runs (calibration history, standing faults): never the developer's own
    os.environ["DYNO_STATE_DIR"] = str(tmp_path_factory.mktemp("state"))
    yield
    for name, value in old.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
