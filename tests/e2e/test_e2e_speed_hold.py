"""`dyno run --plan speed-hold`: closed-loop speed setpoints on the simulated rig (its actuator, relay and
CVT keep the real ones' limits), points to a 95 % CI of +-1 pp, the sim's truth inside it."""

import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.session.summary import public_point
from dyno.control.plans import plan_named
from dyno.session.drills import parse_drill
from dyno.runlog.replay import replay

from .conftest import IDEAL  # perfect knowledge: this test checks the statistics alone

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def hold_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("hold") / "run"
    # no --plan: speed-hold is the default plan
    r = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--json", "--sim-ideal", "--seed", "2",
                        "--out", str(out)], capture_output=True, text=True, timeout=600,
                       env={**os.environ, "PYTHONPATH": str(REPO)})
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "meta.json").read_text())["plan"]["name"] == "speed-hold"
    return json.loads(r.stdout)


def test_speed_hold_steady_test_figures(hold_run):
    r = hold_run
    assert r["state"] == "done" and not r["aborts"]
    pts = r["points"]
    # 19 of 20 setpoints on seeds 1-4: the hold (with its position term) holds the secondary across the CVT's
    # shift, from the overdrive stop to the logs' ratio 2.35 (the lowest setpoint is skipped with its reason)
    assert len(pts) >= 17
    assert r["test_time_s"] <= 190.0  # GO to the end of the last measurement, simulated s (167-181 on seeds 1-4)
    assert all(p["efficiency_ci95"] <= 0.01 for p in pts)  # every point to +-1 pp (95 %)
    # The CI is the point's own statistics; the tare (the zero read before GO, ~0.04 N·m standard uncertainty)
    # is one error for the whole run, stated in the systematic part (efficiency_sys95_calibration).  Seed 2's
    # tare reads 0.067 N·m off (1.8 of its sigma): +0.2 to +0.9 pp on every point, which the CI does not claim.
    # --sim-ideal makes the sensor exactly its calibration, so the tare's own error is what it read against the
    # calibration's intercept (zero_nm); the CI is judged on what is left (mean error then 0.0002).
    zero_nm = r["torque_tare"]["zero_nm"]
    err = [p["efficiency"] - p["efficiency_true"] * (1.0 - zero_nm / p["torque_secondary_true_nm"]) for p in pts]
    inside = sum(abs(e) <= p["efficiency_ci95"] for e, p in zip(err, pts))
    assert inside / len(pts) >= 0.85  # (90-95 % on seeds 1-4)
    assert statistics.median(abs(e) for e in err) <= 0.005
    # warm-up criterion met and recorded; the systematic part stated beside the CI (and larger than it)
    assert r["warmup"]["criterion"] == "time at load" and r["warmup"]["at_load_s"] >= r["warmup"]["required_s"] - 1e-6 > 0
    assert all(p["efficiency_sys95"] > p["efficiency_ci95"] for p in pts)
    assert all(p["efficiency_sys95_calibration"] > 0 and p["efficiency_sys95_engine_map"] > 0 for p in pts)
    rs = [p["rpm_secondary"] for p in pts]
    assert max(rs) - min(rs) > 2500  # over the range, light load to the low end


def test_speed_hold_replays_exactly(hold_run):
    again = replay(hold_run["run_dir"])["points"]
    assert len(again) == len(hold_run["points"])
    for live, rep in zip(hold_run["points"], again):
        assert public_point(rep) == live  # every public key, exactly


def test_a_drill_during_a_hold_still_trips_within_its_bound(tmp_path):
    r = run_test(RunSpec(sim=True, seed=2, out_dir=tmp_path / "run", plan=plan_named("speed-hold"), sim_params=IDEAL,
                            drills=[parse_drill("bus-lost@95")], handle_signals=True))
    assert r["state"] == "aborted"
    a = r["aborts"][0]
    assert a["cause"] == "comms_lost" and a["latency_s"] <= 0.35 and r["rig_safe"]
    assert len(r["points"]) >= 2 and a["state"] in ("step", "settle", "measure")  # under the hold
