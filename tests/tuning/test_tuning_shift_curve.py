"""Predicted shift curve: force balance and tuning directions.

Exercises Messick eq. 9.3 (primary), Sorge & Cammalleri eq. 22 (secondary)
against the belt's closed-form thrusts (Sorge & Cammalleri eqs. 17-18 via
dyno.model.closed_form).
"""

from pathlib import Path

import numpy as np
import pytest

from dyno.model.closed_form import closed_form_point
from dyno.model.params import OperatingPoint
from dyno.tuning import actuators as act
from dyno.tuning.shift_curve import (EngineMap, compare_to_measured, key_speeds_rpm, load_engine_map,
                                     predict_shift_curve, sensitivities)
from dyno.tuning.tune import model_params_for
from dyno.tuning.tune import load_tune

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

ROOT = Path(__file__).resolve().parents[2]
TUNE = load_tune(ROOT / "calibration/tunes/cvtech-stock.toml")
# Built in the test so it does not depend on other owners' files.
ENGINE = EngineMap((1500, 1900, 2400, 2800, 3200, 3500, 3700, 3850),
                   (15.2, 16.9, 18.6, 18.2, 17.2, 15.4, 9.0, 0.0), "test map")


@pytest.fixture(scope="module")
def curve():
    return predict_shift_curve(TUNE, ENGINE, n_points=30)


def test_force_balance_holds_at_every_shifting_point(curve):
    # At each predicted point the primary actuator force (eq. 9.3) is the
    # belt's primary thrust, and the secondary actuator (eq. 22) equals the
    # closed-form secondary thrust the belt then requires (eq. 18).
    params = model_params_for(TUNE)
    shifting = [p for p in curve.points if p.segment == "shifting"]
    assert len(shifting) >= 25
    for p in shifting:
        f_p = act.primary_axial_force_n(TUNE, p.engine_rpm, p.primary_radius_m)
        assert f_p == pytest.approx(p.primary_force_n, rel=1e-9)
        res = closed_form_point(params, OperatingPoint(ratio=p.ratio, primary_speed_rpm=p.engine_rpm,
                                                       primary_torque_nm=p.engine_torque_nm, slack_tension_n=None,
                                                       primary_axial_force_n=f_p))
        f_s = act.secondary_axial_force_n(TUNE, p.engine_torque_nm * p.ratio, res.r_secondary_m)
        assert f_s == pytest.approx(res.axial_force_secondary_n, abs=0.5)  # N, brentq xtol 0.01 rpm
        assert p.engine_torque_nm == pytest.approx(ENGINE.torque_at_nm(p.engine_rpm))


def test_curve_shape(curve):
    a = curve.arrays()
    assert np.all(np.diff(a["ratio"][[p.segment == "shifting" for p in curve.points]]) < 0)
    assert np.all(np.diff(a["secondary_rpm"]) > 0)
    assert curve.engagement_rpm < curve.shift_out_rpm
    # the stock profile's steep first 3 mm (docs/belt-model.md): at full throttle the sheave leaves the low
    # stop late and snaps over a fold; the drive cannot sit on the fold's inner balances, the curve skips them
    assert curve.jumped and all(p.ratio < curve.ratio_low_stop for p in curve.jumped)
    landed = min(p.ratio for p in curve.jumped)  # after the jump the engine speed rises with the upshift
    stable = [p for p in curve.points if p.segment == "shifting" and p.ratio < landed]
    assert np.all(np.diff([p.engine_rpm for p in stable]) > -15.0)  # (a shallow dip as it lands)
    assert max(p.engine_rpm for p in stable) <= curve.full_shift_rpm + 1
    assert np.all((a["efficiency"] > 0.9) & (a["efficiency"] <= 1.0))


def test_stiffer_primary_spring_raises_engagement_rpm():
    # Eq. 9.3: engagement where n m r (dr/dz) w^2 = spring preload.
    base = key_speeds_rpm(TUNE, ENGINE)
    s = TUNE.primary_spring
    stiff = TUNE.with_changes(**{"primary_spring.preload_n": s.preload_n * 1.2,
                                 "primary_spring.rate_n_per_m": s.rate_n_per_m * 1.2})
    k = key_speeds_rpm(stiff, ENGINE)
    assert k["engagement_rpm"] > base["engagement_rpm"] + 50
    assert k["shift_out_rpm"] > base["shift_out_rpm"]
    # and the engagement speed scales as sqrt(preload) (eq. 9.2: F ~ w^2)
    assert k["engagement_rpm"] / base["engagement_rpm"] == pytest.approx(np.sqrt(1.2), rel=1e-4)


def test_heavier_flyweights_lower_the_shift_rpm():
    base = key_speeds_rpm(TUNE, ENGINE)
    heavy = key_speeds_rpm(TUNE.with_changes(**{"flyweights.mass_each_kg": 0.228 + 0.020}), ENGINE)
    assert heavy["shift_out_rpm"] < base["shift_out_rpm"] - 30
    assert heavy["full_shift_rpm"] < base["full_shift_rpm"] - 30
    assert heavy["engagement_rpm"] < base["engagement_rpm"]


def test_sensitivity_signs_and_units():
    sens = sensitivities(TUNE, ENGINE, parameters=(
        ("flyweights.mass_each_kg", 0.005, "rpm/g", 1e-3),
        ("secondary_spring.torsion_preload_nm", 0.2, "rpm/(N m)", 1.0)))
    assert sens["flyweights.mass_each_kg"]["shift_out_rpm"] < 0  # rpm per gram
    assert -50 < sens["flyweights.mass_each_kg"]["shift_out_rpm"] < -0.5
    # a stiffer secondary (more helix pre-torque) holds the belt: shift rpm up
    assert sens["secondary_spring.torsion_preload_nm"]["shift_out_rpm"] > 0


def test_engine_map_formats(tmp_path):
    p = tmp_path / "hp.csv"
    p.write_text("rpm,power_hp\n2000,5\n3000,8\n")
    assert load_engine_map(p).torque_at_nm(2000) == pytest.approx(5 * 745.699872 / (2000 * np.pi / 30), rel=1e-4)
    p = tmp_path / "thesis.csv"
    p.write_text("1548.76,3.40\n1655.04,3.95\n1752.96,4.31\n")
    assert load_engine_map(p).speed_rpm[0] == 1548.76
    p.write_text("# comment\nrpm,power_kw\n2000,4\n3000,6\n")
    assert load_engine_map(p).torque_at_nm(3000) == pytest.approx(6000 / (3000 * np.pi / 30))


def test_compare_to_measured(curve):
    a = curve.arrays()
    meas = [{"secondary_rpm": s, "engine_rpm": e + 10} for s, e in zip(a["secondary_rpm"][5:9], a["engine_rpm"][5:9])]
    cmp = compare_to_measured(curve, meas)
    assert cmp["mean_rpm"] == pytest.approx(10, abs=1e-6)


def test_cli_shift_curve(tmp_path, capsys):
    from dyno.cli import main

    emap = tmp_path / "map.csv"
    emap.write_text("rpm,torque_nm\n" + "\n".join(f"{n},{t}" for n, t in zip(ENGINE.speed_rpm, ENGINE.torque_nm)))
    png = tmp_path / "c.png"
    assert main(["shift-curve", str(ROOT / "calibration/tunes/cvtech-stock.toml"), "--engine-map", str(emap),
                 "--points", "10", "--no-sensitivity", "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "engagement" in out and png.exists()
    assert main(["shift-curve", str(tmp_path / "missing.toml")]) == 2
