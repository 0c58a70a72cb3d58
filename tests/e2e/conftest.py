import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.control.api import TestPlan
from dyno.sim.rig_params import RigParams
from tests.rig_files import rig_without_run_enable  # noqa: F401 (the e2e tests import it from here)

# Perfect knowledge (the engine exactly its map, the sensor exactly its calibration, the J1349 reference
# day: dyno.sim.world): for the tests that check the statistics alone (CI coverage, lost data, replay
# equality). Accuracy against the truth with the simulated rig's own engine, sensor and day is
# tests/e2e/test_e2e_honest_numbers.py and bench/bench_uncertainty.py.
IDEAL = RigParams(ideal=True)

# A run's start-up: the simulated driver holds the ignition off until its first release has run the full stroke
# (+ 10 % + 50 ms: dyno.sim.rig), the brake's position being unknown (docs/safety.md, "Start-up and gaps"). A
# drill timed from the first frame to land in a state of the test comes this much later than it would without.
STARTUP_HOLD_S = 8.0 * 1.1 + 0.05


def bench_safe_state_module():
    """bench/bench_safe_state.py as a module (its plans x drills matrix: the tests run its rows)."""
    bench = str(Path(__file__).resolve().parents[2] / "bench")
    sys.path.insert(0, bench)
    try:
        import bench_safe_state
    finally:
        sys.path.remove(bench)
    return bench_safe_state

def tare_allowance(result: dict, point: dict) -> float:
    """What the tare (the zero read at rest before GO, ±u_nm) can move a point's efficiency by (~99 %):
    even with perfect knowledge the zero is *measured*, so a test of the statistics alone allows it."""
    tare = result.get("torque_tare") or {}
    t = abs(point.get("torque_secondary_nm") or 0.0)
    return 2.6 * point["efficiency"] * tare.get("u_nm", 0.0) / t if t > 0 else 0.0


def tare_error(result: dict, point: dict) -> float:
    """What the tare's own error moved the point's efficiency by (a fraction).  In the ideal world the sensor is
    exactly its calibration and the secondary is at rest when the zero is read (idle is below engagement), so
    the zero read (``torque_tare.zero_nm``) is the tare's error: every point's torque reads low by it.  The zero
    is one measurement that every point shares, its noise set by when the run reads it."""
    tare = result.get("torque_tare") or {}
    t = point.get("torque_secondary_nm") or 0.0
    return -point["efficiency"] * tare.get("zero_nm", 0.0) / t if t else 0.0


# A shorter plan for tests that only need a few points (aborts, kills).
QUICK_PLAN = replace(TestPlan(), max_measure_s=3.0, warmup_s=2.0)


@pytest.fixture(scope="session")
def full_run(tmp_path_factory):
    """One complete default simulated test, shared by the tests that inspect it."""
    out = tmp_path_factory.mktemp("runs") / "full"
    return run_test(RunSpec(sim=True, seed=1, out_dir=out, sim_params=IDEAL))


@pytest.fixture(scope="session")
def faulty_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "faulty"
    return run_test(RunSpec(sim=True, seed=1, fault_rate=0.05, out_dir=out, sim_params=IDEAL))


@pytest.fixture(scope="session")
def cli_run(tmp_path_factory):
    """`dyno run --sim --headless --json` as a real process, once: (run directory, its JSON document).

    Shared by the entry-point and report tests (the run ends by writing report.html).
    """
    work = tmp_path_factory.mktemp("cli")
    run_dir = work / "run"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    proc = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--json", "--seed", "3",
                           "--out", str(run_dir)], capture_output=True, text=True, timeout=300, cwd=work, env=env)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    return run_dir, json.loads(proc.stdout)



def drill_as_the_user_runs_it(out: Path, *drill_args: str) -> dict:
    """``dyno run --sim --headless --json --out OUT ARGS...`` as a real process: it must exit 3 (aborted to the safe
    state), and ``dyno replay --json`` of its run directory exit 0 with every point it reported (nothing recorded
    was lost).  Its JSON document."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    p = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--json", "--out", str(out),
                        *drill_args], capture_output=True, text=True, env=env, timeout=600)
    assert p.returncode == 3, p.stderr[-2000:]
    r = json.loads(p.stdout)
    q = subprocess.run([sys.executable, "-m", "dyno", "replay", "--json", str(out)], capture_output=True,
                       text=True, env=env, timeout=300)
    assert q.returncode == 0, q.stderr[-2000:]
    assert len(json.loads(q.stdout)["points"]) == len(r["points"])
    return r
