"""A plan's `throttle` step below full throttle, as a user runs it: every point records the commanded
throttle (`throttle_frac`); its efficiency comes from the engine map's curve at that throttle, or is null
with a reason naming the throttle when the map has none (torque, speeds, ratio, output power kept);
`dyno replay` reproduces the points exactly.  (The bug this guards: part-throttle points divided by the
FULL-throttle map: 0.34 for a true 0.80 in the governor's band.)"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.analysis.engine_map import RAD_PER_S_PER_RPM, load_engine_map

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
FULL_MAP = REPO / "calibration" / "engine_maps" / "baja-10hp-representative.csv"
PART_MAP = REPO / "calibration" / "engine_maps" / "baja-10hp-representative-part-throttle.csv"
# Throttle 0.6 (governed speed ~3,130 rpm) with the CVT at full shift: light loads put the engine in
# the governor's band, where the torque is far below the full-throttle curve.
PLAN = """schema = "dyno.plan/1"
name = "part-throttle"
mode = "steps"
[test]
measure_s = 2.0
target_efficiency_ci95 = 0.01
max_measure_s = 10.0
[[step]]
kind = "throttle"
fraction = 0.6
[[step]]
kind = "wait"
s = 2.0
[[step]]
kind = "contact"
[[step]]
kind = "hold"
variable = "secondary"
setpoints = [4250.0, 4200.0, 4100.0]
"""


def _dyno(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=ENV)


def _run(tmp_path_factory, name: str, *extra):
    d = tmp_path_factory.mktemp(name)
    (d / "plan.toml").write_text(PLAN)
    r = _dyno("run", "--sim", "--headless", "--json", "--sim-ideal", "--seed", "4", "--plan", d / "plan.toml",
              "--out", d / "run",
              *extra)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert len(res["points"]) == 3, res["points"]
    return res, d / "run"


@pytest.fixture(scope="module")
def full_map_run(tmp_path_factory):
    """The default (full-throttle only) map."""
    return _run(tmp_path_factory, "full-map")


@pytest.fixture(scope="module")
def part_map_run(tmp_path_factory):
    return _run(tmp_path_factory, "part-map", "--engine-map", PART_MAP)


@pytest.mark.parametrize("which", ["full_map_run", "part_map_run"])
def test_every_point_records_its_throttle_and_replay_is_exact(request, which):
    res, out = request.getfixturevalue(which)
    for p in res["points"]:
        assert p["throttle_frac"] == 0.6
        assert p["valid"] is True
        assert p["torque_secondary_nm"] > 0 and p["power_out_w"] > 0 and p["ratio"] > 0
    rep = _dyno("replay", "--json", out)
    assert rep.returncode == 0, rep.stderr
    assert json.loads(rep.stdout)["points"] == res["points"]


def test_without_a_part_throttle_curve_efficiency_is_null_with_a_reason(full_map_run):
    res, _ = full_map_run
    for p in res["points"]:
        assert p["efficiency"] is None and p["efficiency_ci95"] is None and p["efficiency_sys95"] is None
        assert "throttle 0.60" in p["efficiency_reason"]


def test_with_a_part_throttle_map_efficiency_follows_the_sims_truth(part_map_run):
    res, _ = part_map_run
    full = load_engine_map(FULL_MAP)
    wrong = []
    # --sim-ideal: the sensor is exactly its calibration, so the tare's own error is what it read against the
    # calibration's intercept (zero_nm; seed 4: 0.045 N·m, +0.5 pp at these light loads): one error for the whole
    # run, stated in the systematic part, not the CI -- judged net of it
    zero_nm = res["torque_tare"]["zero_nm"]
    for p in res["points"]:
        assert p["efficiency_reason"] is None
        truth = p["efficiency_true"] * (1.0 - zero_nm / p["torque_secondary_true_nm"])
        # one short window's 95 % interval misses 1 point in 20 by design (seeds 1-9: 25 of 27 points within
        # it, all within 1.9x; seed 4's first point, 1.7x, has a window whose CI came out at half the usual);
        # the bug this guards put the efficiency 46 pp off
        assert abs(p["efficiency"] - truth) <= 2.0 * p["efficiency_ci95"], (p, truth)
        assert p["efficiency_sys95"] > 0  # the systematic part is still stated
        # what the full-throttle map would have said (the bug)
        wrong.append(p["power_out_w"] / (full.torque_nm(p["rpm_primary"]) * p["rpm_primary"] * RAD_PER_S_PER_RPM))
    # (0.27 on the logs' plant, whose part-throttle points sit at other speeds; 0.3+ on the old one)
    assert max(abs(w - p["efficiency_true"]) for w, p in zip(wrong, res["points"])) > 0.2
