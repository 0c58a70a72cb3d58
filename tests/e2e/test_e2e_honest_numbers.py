"""Honest numbers, on real processes: the simulated rig is its own engine, sensor and day (the host is told
only what an operator knows), and every point's efficiency_interval95 is judged against the simulator's truth."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.analysis.engine_map import load_engine_map

REPO = Path(__file__).resolve().parents[2]
SHORT_PLAN = (REPO / "bench" / "bench_uncertainty.py").read_text().split('SHORT_PLAN = """', 1)[1].split('"""', 1)[0]


def _run(tmp_path, *args, rig_sensor=False):
    plan = tmp_path / "short.toml"
    plan.write_text(SHORT_PLAN)
    cmd = [sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--json", "--plan", str(plan),
           "--out", str(tmp_path / "run"), *args]
    if not rig_sensor:  # the shipped rig file fits a BME280: a rig without one says so
        rig = tmp_path / "rig.toml"
        rig.write_text((REPO / "hardware" / "rig.toml").read_text().replace('sensor = "bme280"', 'sensor = "none"', 1))
        cmd += ["--rig", str(rig)]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    return json.loads(proc.stdout), tmp_path / "run"


def _covered(points):
    pts = [p for p in points if p.get("efficiency") is not None]
    assert pts, "no efficiency points"
    for p in pts:
        lo, hi = p["efficiency_interval95"]
        assert lo <= p["efficiency_true"] <= hi <= 1.0, (p["efficiency"], p["efficiency_true"], p["efficiency_u95_terms"])
    return pts


def test_hot_high_day_without_a_sensor_is_uncorrected_and_covered(tmp_path):
    result, run_dir = _run(tmp_path, "--seed", "5", "--sim-ambient", "35,90,20")
    assert result["ambient"]["source"] == "none" and result["ambient"]["j1349_factor"] is None
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["ambient"]["source"] == "none"
    # the physics: on this day the engine made ~13 % less than its map, so the map-based efficiency is low
    assert result["sim_world"]["j1349_factor"] == pytest.approx(1.156, abs=0.002)
    pts = _covered(result["points"])
    assert all(p["efficiency"] < p["efficiency_true"] for p in pts)
    assert all(p["efficiency_u95_terms"]["air"] > 0.1 for p in pts)  # the air term covers a plausible day
    # and the interval is the day's: far more room above the figure than below it
    assert all(p["efficiency_interval95"][1] - p["efficiency"] > 2 * (p["efficiency"] - p["efficiency_interval95"][0])
               for p in pts)
    assert "uncorrected" in (run_dir / "report.html").read_text()


def test_with_the_sensor_the_j1349_factor_is_applied_and_logged(tmp_path):
    result, run_dir = _run(tmp_path, "--seed", "5", "--sim-ambient", "35,90,20", rig_sensor=True)
    amb = result["ambient"]
    assert amb["source"] == "sensor"
    assert amb["temp_c"] == pytest.approx(35.0, abs=2.0) and amb["pressure_kpa"] == pytest.approx(90.0, abs=0.2)
    # the sensor's own error (data sheet accuracy) is all that separates the host's factor from the truth's
    assert amb["j1349_factor"] == pytest.approx(result["sim_world"]["j1349_factor"], rel=0.01)
    assert amb["end"]["source"] == "sensor"  # read again after the run
    # what each u95 term assumes, in the run's JSON, meta.json and the report
    terms = {t["term"]: t for t in result["u95_terms"]}
    assert list(terms) == ["statistical", "calibration", "engine_map", "engine_wear", "air", "driveline"]
    assert terms["engine_map"]["u_rel"] == 0.10 and "stated in the map file" in terms["engine_map"]["basis"]
    assert terms["engine_map"]["measured"] is False  # the shipped map is no engine's: it says so
    assert "BME280" in terms["air"]["basis"] and terms["air"]["u_rel"] < 0.005
    assert json.loads((run_dir / "meta.json").read_text())["uncertainty"]["u95_terms"] == result["u95_terms"]
    assert "What efficiency_u95 assumes" in (run_dir / "report.html").read_text()
    docs = [json.loads(x) for x in (run_dir / "documents.jsonl").read_text().splitlines() if x.strip()]
    assert [d for d in docs if d.get("type") == "ambient"][0]["j1349_factor"] == amb["j1349_factor"]
    emap = load_engine_map(REPO / "calibration" / "engine_maps" / "baja-10hp-representative.csv")
    pts = _covered(result["points"])
    for p in pts:  # input power is the map's, at this day (less what the crank's inertia took: I·alpha)
        crank_w = p.get("inertia_torque_engine_nm", 0.0) * p["rpm_primary"] * 2.0 * math.pi / 60.0
        assert (p["power_in_w"] + crank_w) * amb["j1349_factor"] == pytest.approx(emap.power_w(p["rpm_primary"]),
                                                                                   rel=2e-3)
        assert p["efficiency_u95_terms"]["air"] < 0.01
    # replay reproduces the run's numbers from its own record of the air
    from dyno.runlog.replay import replay

    again = replay(run_dir)["points"]
    assert [q["efficiency"] for q in again if q.get("efficiency") == q.get("efficiency")] == pytest.approx(
        [p["efficiency"] for p in pts], rel=1e-9)


def test_a_four_percent_weak_engine_is_still_covered(tmp_path):
    """An engine 4 % down on its map (worn), the day known: the error is the engine's, and u95 covers it."""
    result, _ = _run(tmp_path, "--seed", "2", "--sim-engine-dev", "0", "--sim-engine-ageing", "0.04",
                     "--sim-cal-drift", "0", "--sim-ambient", "25,99,0", "--ambient", "25,99,0")
    pts = _covered(result["points"])
    rels = []
    for p in pts:  # the map overstates the input power by 1/0.96, and the gauge sees the belt's output less the
        # driveline after it (the sim's truth records its share); what is left is the point's scatter and tare
        expect = 0.96 * (1.0 - p["driveline_loss_true_nm"] / p["torque_secondary_true_nm"]) - 1.0
        rel = p["efficiency"] / p["efficiency_true"] - 1.0
        t = p["efficiency_u95_terms"]
        assert abs(rel - expect) * p["efficiency_true"] <= (t["statistical"] ** 2 + t["calibration"] ** 2) ** 0.5
        rels.append(rel - expect)
    assert sum(rels) / len(rels) == pytest.approx(0.0, abs=0.015)


def test_sim_ideal_is_perfect_knowledge(tmp_path):
    result, _ = _run(tmp_path, "--seed", "2", "--sim-ideal")
    w = result["sim_world"]
    assert w["ideal"] and w["adc_gain_drift_rel"] == 0.0 and w["j1349_factor"] == pytest.approx(1.0)
    for p in result["points"]:
        if p.get("efficiency") is not None:  # only the statistics are left
            assert abs(p["efficiency"] - p["efficiency_true"]) < 3 * max(p["efficiency_ci95"], 0.004)
