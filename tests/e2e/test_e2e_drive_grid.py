"""`dyno run --plan drive-grid` as a user runs it (simulated rig, the synthetic part-throttle map): the grid
covers >= 3 throttles x the setpoints, every cell a point or a recorded reason (unreachable setpoints
named as such), the sim's truth inside the 95 % CI at most points, `dyno replay` reproduces points and
grid exactly, the report shows the grid; a bad [drive_grid] table is one line, exit 2."""

import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
PART_MAP = REPO / "calibration" / "engine_maps" / "baja-10hp-representative-part-throttle.csv"


def _dyno(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=ENV)


@pytest.fixture(scope="module")
def grid_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("grid") / "run"
    r = _dyno("run", "--sim", "--headless", "--json", "--sim-ideal", "--seed", "1", "--plan", "drive-grid",
              "--engine-map", PART_MAP, "--out", out)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout), out


def test_the_grid_covers_every_cell_with_a_point_or_a_reason(grid_run):
    res, _ = grid_run
    assert res["state"] == "done"
    grid = res["drive_grid"]
    assert len(grid["throttles"]) >= 3 and grid["throttles"][0] == 1.0
    cells = grid["cells"]
    assert sorted((c["throttle_frac"], c["setpoint_rpm"]) for c in cells) == sorted(
        (u, sp) for u in grid["throttles"] for sp in grid["setpoints_rpm"])
    by_index = {p["index"]: p for p in res["points"]}
    with_point = [c for c in cells if c["index"] is not None]
    assert len(with_point) == len(res["points"]) >= 8
    for c in with_point:  # the cell is its point, measured at the cell's throttle and near its setpoint
        p = by_index[c["index"]]
        assert p["throttle_frac"] == c["throttle_frac"] and p["setpoint_rpm"] == c["setpoint_rpm"]
        assert abs(p["rpm_secondary"] - c["setpoint_rpm"]) <= 0.02 * c["setpoint_rpm"]
        assert c["torque_secondary_nm"] == p["torque_secondary_nm"] and c["efficiency"] == p["efficiency"]
        assert c["efficiency_sys95"] > 0  # the systematic part is stated for part throttle too
    # part-throttle points exist (the map has the curves) and have efficiencies
    assert {c["throttle_frac"] for c in with_point} >= {1.0, 0.8, 0.6}
    for c in cells:
        if c["index"] is None:
            assert c["reason"] and c["efficiency"] is None and c["torque_secondary_nm"] is None
    unreachable = [c for c in cells if c["reason"] and c["reason"].startswith("unreachable at throttle")]
    assert unreachable, "at part throttle the top setpoints are out of the engine's reach"
    for c in unreachable:  # only where the throttle is below full, and each names its throttle
        assert c["throttle_frac"] < 1.0 and f"throttle {c['throttle_frac']:.2f}" in c["reason"]
    # a light-load part-throttle cell (the governor's band): where the full-throttle map would be wrong
    assert any(c["throttle_frac"] == 0.6 and c["setpoint_rpm"] >= 4100 and c["index"] is not None for c in cells)


def test_the_sims_truth_lies_inside_the_ci_at_most_points(grid_run):
    res, _ = grid_run
    pts = [p for p in res["points"] if p["efficiency"] is not None]
    inside = sum(abs(p["efficiency"] - p["efficiency_true"]) <= p["efficiency_ci95"] for p in pts)
    assert inside >= 0.8 * len(pts), (inside, len(pts))
    assert statistics.median(abs(p["efficiency"] - p["efficiency_true"]) for p in pts) <= 0.005
    assert max(p["efficiency_ci95"] for p in pts) <= 0.01


def test_replay_reproduces_points_and_grid_and_the_report_shows_it(grid_run):
    res, out = grid_run
    rep = _dyno("replay", "--json", out)
    assert rep.returncode == 0, rep.stderr
    again = json.loads(rep.stdout)
    assert again["points"] == res["points"]
    assert again["drive_grid"] == res["drive_grid"]
    html = (out / "report.html").read_text()
    assert 'id="drive-grid"' in html
    for u in res["drive_grid"]["throttles"]:
        assert f"{100 * u:.0f} %" in html
    assert "unreachable at throttle" in html


def test_a_bad_drive_grid_table_is_one_line_exit_2(tmp_path):
    plan = tmp_path / "bad.toml"
    plan.write_text('schema = "dyno.plan/1"\nmode = "drive-grid"\n[drive_grid]\nthrottles = [1.0, 1.5]\n')
    r = _dyno("run", "--sim", "--headless", "--plan", plan, "--out", tmp_path / "run", timeout=60)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "drive_grid.throttles" in lines[0] and str(plan) in lines[0], r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "run").exists()
