"""Issue 39's must-show for the default plan's time, in process: the default plan (speed-hold) with perfect
knowledge (``--sim-ideal``: the statistics alone), three seeds, judged by the sim's truth."""

import tempfile
from pathlib import Path

import pytest

from dyno.session.root import RunOptions, run_test
from dyno.control.plans import plan_named
from dyno.sim.rig_params import RigParams

SEEDS = (1, 2, 3)


@pytest.fixture(scope="module")
def runs():
    with tempfile.TemporaryDirectory() as tmp:
        return [run_test(RunOptions(sim=True, seed=s, plan=plan_named("speed-hold"), out_dir=Path(tmp) / str(s),
                                    sim_params=RigParams(ideal=True))) for s in SEEDS]


def test_the_default_curve_has_18_points_each_within_1_pp_and_the_truth_inside(runs):
    inside = total = 0
    for r in runs:
        pts = r["points"]
        assert r["state"] == "done" and len(pts) >= 18
        assert all(p["efficiency_ci95"] <= 0.01 for p in pts)
        inside += sum(abs(p["efficiency"] - p["efficiency_true"]) <= p["efficiency_ci95"] for p in pts)
        total += len(pts)
        # where it stands today (docs/measurements/2026-11-29-test-time.md): 112-117 s, was 179 s
        assert r["test_time_s"] <= 125.0
    assert inside >= 0.85 * total


@pytest.mark.xfail(strict=True, reason="issue 39 part 4 not met yet: 112-117 s on seeds 1-3 "
                                       "(docs/measurements/2026-11-29-test-time.md); strict: passing flags it done")
def test_the_default_curve_takes_at_most_100_s(runs):
    assert all(r["test_time_s"] <= 100.0 for r in runs)
