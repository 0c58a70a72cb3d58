"""Slip-consistent inverse (dyno.model.inverse): measured speed ratio -> geometric ratio and slip."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.errors import GrossSlip
from dyno.model import inverse as inv
from dyno.model.closed_form import closed_form_point
from dyno.model.params import TABLE_6_1, OperatingPoint
from dyno.tuning.tune import model_params_for
from dyno.tuning.tune import load_tune

ROOT = Path(__file__).resolve().parents[2]
STOCK = ROOT / "calibration" / "tunes" / "cvtech-stock.toml"


def test_closed_form_round_trip_at_the_tunes_clamp():
    """Forward model at a known geometric ratio -> speed ratio -> inverse recovers ratio and slip."""
    tune = load_tune(STOCK)
    params = model_params_for(tune)
    slip = inv.slip_closed_form(params)
    for ratio, rpm, torque in ((0.75, 3600.0, 9.0), (1.0, 3150.0, 16.0), (1.6, 3100.0, 17.5), (2.3, 3000.0, 12.0)):
        clamp = inv.clamp_from_tune(tune, rpm)
        op = OperatingPoint(ratio=ratio, primary_speed_rpm=rpm, primary_torque_nm=torque, slack_tension_n=None,
                            primary_axial_force_n=clamp(ratio))
        s_true = 1.0 - closed_form_point(params, op).efficiency_speed
        assert 1e-4 < s_true < 0.01
        res = inv.invert_speed_ratio(ratio / (1.0 - s_true), rpm, torque, slip=slip, clamp=clamp)
        assert res.ok and res.tier == "closed_form" and res.iterations <= 6
        assert res.geometric_ratio == pytest.approx(ratio, rel=1e-8)
        assert res.slip == pytest.approx(s_true, abs=1e-9)
        assert res.primary_axial_force_n == pytest.approx(clamp(ratio), rel=1e-6)
        back = res.operating_point()
        assert back.primary_axial_force_n == res.primary_axial_force_n and back.slack_tension_n is None


def test_clamp_follows_the_tune():
    """Flyweights go as rpm^2: more clamp at higher speed; the spring holds the sheave open at idle."""
    tune = load_tune(STOCK)
    assert inv.clamp_from_tune(tune, 3400.0)(1.0) > inv.clamp_from_tune(tune, 3000.0)(1.0) > 0.0
    res = inv.invert_speed_ratio(2.0, 1200.0, 5.0, slip=inv.slip_closed_form(model_params_for(tune)),
                                 clamp=inv.clamp_from_tune(tune, 1200.0))
    assert res.state == "no_clamp" and "spring" in res.reason and math.isnan(res.geometric_ratio)


def test_failures_are_states_with_reasons():
    def gross(op):
        raise GrossSlip("gross slip: the belt cannot transmit 18 N*m at this tension level")

    gross.tier = "full"
    res = inv.invert_speed_ratio(1.2, 3000.0, 18.0, slip=gross, clamp=600.0)
    assert res.state == "gross_slip" and "cannot transmit" in res.reason and not res.ok
    with pytest.raises(ValueError, match="no operating point"):
        res.operating_point()

    class Table:
        errors = {(1.2, 18.0): "gross slip: the belt cannot transmit 18 N*m"}

        def lookup(self, ratio, torque):
            return None if torque > 10 else (0.95, 0.99)

    res = inv.invert_speed_ratio(1.2, 3000.0, 18.0, slip=inv.slip_table(Table()), clamp=600.0)
    assert res.state == "gross_slip" and res.tier == "table"
    res = inv.invert_speed_ratio(1.2, 3000.0, 8.0, slip=inv.slip_table(Table()), clamp=600.0)
    assert res.ok and res.slip == pytest.approx(0.01, abs=1e-12) and res.geometric_ratio == pytest.approx(1.188)
    assert inv.invert_speed_ratio(math.nan, 3000.0, 8.0, slip=inv.slip_table(Table()), clamp=600.0).state == "failed"


def test_without_a_tune_the_slack_tension_sets_the_level():
    (rs, res), = inv.invert_points([{"rpm_primary": 3400.0, "rpm_secondary": 3400.0 / 1.01, "ratio": 1.01,
                                     "power_in_w": 18.0 * 3400.0 * math.pi / 30.0}])
    op = res.operating_point()
    assert res.ok and op.slack_tension_n == 100.0 and op.primary_torque_nm == pytest.approx(18.0)
    s_true = 1.0 - closed_form_point(TABLE_6_1, op).efficiency_speed
    assert res.slip == pytest.approx(s_true, abs=1e-9) and res.geometric_ratio == pytest.approx(1.01 * (1 - s_true))


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory):
    """A simulated steady-state test, started as the user starts it (~10-20 s).  Perfect knowledge
    (--sim-ideal): the inverse takes the primary torque from the engine map, so an engine unlike its map
    (dyno.sim.world) moves its input; this checks the inverse, not the map.  And the belt of the capstan
    tier (--sim-belt-thrust 0.4), whose slip is the closed form's creep, the tier this inverse uses: the
    default rig's slip is the full belt model's (up to ~4 %), which only the full tier's inverse can match."""
    out = tmp_path_factory.mktemp("inverse-run") / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--sim-ideal", "--sim-belt-thrust", "0.4",
                           "--seed", "3", "--out", str(out), "--json"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    points = [d for d in map(json.loads, (out / "documents.jsonl").read_text().splitlines()) if d["type"] == "point"]
    return out, points


def test_inverse_recovers_the_simulators_true_ratio_and_slip(sim_run):
    """Every point of `dyno run --sim`: geometric ratio and slip against the sim's truth.

    The sim's slip here is the closed-form creep at the tune's clamp (the same tier the
    inverse uses, see the fixture), so this checks the inversion and its inputs (measured speed
    ratio and rpm, engine-map torque, the tune's clamp at the measured rpm), not the
    slip model itself; docs/belt-model.md states the measured errors.
    """
    run_dir, points = sim_run
    valid = [p for p in points if p.get("valid")]
    assert len(valid) >= 10
    results = inv.invert_points(valid, load_tune(run_dir / "tune.toml"))
    assert len(results) == len(valid)
    worst_ratio = worst_slip = 0.0
    for (_, res), p in zip(results, valid):
        assert res.ok, res.reason
        assert p["ratio_geometric_true"] > 0 and 0.0 < p["belt_slip_true"] < 0.01
        worst_ratio = max(worst_ratio, abs(res.geometric_ratio / p["ratio_geometric_true"] - 1.0))
        worst_slip = max(worst_slip, abs(res.slip - p["belt_slip_true"]))
        # the speed ratio really is the geometric ratio less the slip (the truth's own identity)
        assert p["ratio_geometric_true"] / (1.0 - p["belt_slip_true"]) == pytest.approx(
            p["rpm_primary_true"] / p["rpm_secondary_true"], rel=2e-4)
    # measured (seeds 1 and 3): ratio within 4e-5 relative (the measured speed ratio's noise), slip 1e-5
    assert worst_ratio < 2e-4
    assert worst_slip < 2e-4


def test_overlay_inputs_use_the_inverse(sim_run):
    from dyno.model.overlay_inputs import overlay_inputs

    run_dir, points = sim_run
    valid = [p for p in points if p.get("valid")]
    pairs = overlay_inputs(valid, run_dir / "tune.toml")
    assert len(pairs) == len(valid)
    tune = load_tune(run_dir / "tune.toml")
    for (rs, op), p in zip(pairs, valid):
        assert rs == p["rpm_secondary"]
        assert op.ratio == pytest.approx(p["ratio_geometric_true"], rel=2e-4) and op.ratio < p["ratio"]
        assert op.slack_tension_n is None
        assert op.primary_axial_force_n == pytest.approx(inv.clamp_from_tune(tune, p["rpm_primary"])(op.ratio))


def test_cli_model_inverse_reports_ratio_and_slip(sim_run, tmp_path):
    """`dyno model inverse RUN` as a real process: both numbers per point, the truth alongside."""
    run_dir, points = sim_run
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "dyno", "model", "inverse", str(run_dir), "--json"], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["clamp"] == "tune 'cvtech-stock'" and data["tier"] == "closed_form"
    rows = data["points"]
    assert len(rows) == sum(bool(p.get("valid", True)) for p in points)
    for r in rows:
        assert r["state"] == "steady"
        assert r["geometric_ratio"] == pytest.approx(r["ratio_geometric_true"], rel=2e-4)
        assert r["slip"] == pytest.approx(r["belt_slip_true"], abs=2e-4)
        assert r["speed_ratio"] == pytest.approx(r["geometric_ratio"] / (1 - r["slip"]), rel=1e-9)
    text = subprocess.run([sys.executable, "-m", "dyno", "model", "inverse", str(run_dir)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=120)
    assert text.returncode == 0 and "geometric" in text.stdout and "slip %" in text.stdout
    bad = subprocess.run([sys.executable, "-m", "dyno", "model", "inverse", str(tmp_path / "nothing")], cwd=ROOT,
                         env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "meta.json" in bad.stderr and "Traceback" not in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1
