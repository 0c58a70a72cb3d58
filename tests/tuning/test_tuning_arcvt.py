"""AR-CVT actuation (van Kerkhoven 2006) against the report."""

import math

import numpy as np
import pytest

from dyno.tuning import arcvt

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

P = arcvt.ArcvtParams()


def test_table_3_1_geometry_extremes():
    # Eq. 3.3 solved numerically: R_a 30..101 mm -> a_h 279..151 mm (Table 3.1).
    ext = arcvt.geometry_extremes(P)
    assert ext["centre_distance_max_m"] == pytest.approx(0.279, abs=1e-6)  # defines L
    assert ext["centre_distance_min_m"] == pytest.approx(0.151, abs=1.0e-3)  # ours 150.4 mm


def test_eq_3_3_residual_and_wrap():
    for ra in (0.03, 0.06, 0.101):
        a = arcvt.centre_distance_m(ra, P)
        assert abs(float(arcvt.belt_length_residual_m(a, ra, P))) < 1e-12
        beta = float(arcvt.wrap_radial_rad(ra, a, P.radial_radius_m))
        # eq. 3.1 written out with eq. 3.2's wrap
        a31 = (P.belt_length_m - P.radial_radius_m * beta - ra * (2 * math.pi - beta)) / (2 * math.sin(beta / 2))
        assert a31 == pytest.approx(a, rel=1e-12)


def test_eq_3_4_derivative_matches_finite_difference_and_fit():
    h = 1e-6
    for ra in (0.035, 0.06, 0.095):
        fd = (arcvt.centre_distance_m(ra + h, P) - arcvt.centre_distance_m(ra - h, P)) / (2 * h)
        assert arcvt.centre_distance_slope(ra, P) == pytest.approx(fd, rel=1e-6)
    coef, err = arcvt.quadratic_fit(P)
    assert err < 1.5e-3  # eq. 3.5: the report quotes 4e-4 m for its fit; ours is 1.0e-3 m


def test_eq_3_13_forces_and_3_17_3_19_directions():
    ra = 0.07
    a = arcvt.centre_distance_m(ra, P)
    beta = float(arcvt.wrap_radial_rad(ra, a, P.radial_radius_m))
    f_hor, f_vert = arcvt.belt_forces_n(ra, P)
    assert f_hor == pytest.approx(4 * math.tan(math.radians(11)) * 20e3 / (2 * math.pi - beta) * math.sin(beta / 2))
    assert f_vert == pytest.approx(2 * (96 / ra) / beta * (math.sin(beta / 2) - 1))
    cw, ccw = arcvt.actuation(ra, P, True), arcvt.actuation(ra, P, False)
    # the input torque counteracts the actuation force for cw (report Sec. 5.1)
    assert cw["actuation_force_n"] < ccw["actuation_force_n"]
    t_i = 96 * 0.03 / ra
    diff = ccw["actuation_force_n"] - cw["actuation_force_n"]
    assert diff == pytest.approx(2 * t_i / 0.03 - 2 * math.sin(cw["alpha_rad"]) * f_vert)
    # eq. 3.16: alpha changes sign along the trajectory (Fig. 3.8 remark)
    assert arcvt.actuation(0.03, P)["alpha_rad"] > 0 > arcvt.actuation(0.101, P)["alpha_rad"]


def test_table_5_1_max_actuation_torque_with_vroemen_force():
    # Table 5.1: a_act = 240 mm, L_arm = 100 mm, R_i = 30 mm -> max T_act ~ 560 N m.
    p = arcvt.ArcvtParams(horizontal_force_model="vroemen", pivot_distance_m=0.240)
    t = max(abs(arcvt.actuation(float(r), p)["actuation_torque_nm"]) for r in np.linspace(0.03, 0.101, 40))
    assert t == pytest.approx(560, rel=0.05)


def test_trace_shift_rate_and_power():
    # The report's peak ETC shift rate, 35 mm/s, occurs between R_a = 60 and
    # 80 mm: a falling engine speed sweeping R_a down that band at 35 mm/s
    # (an upshift in the report's sense, the direction that needs power).
    t = np.linspace(0, 0.02 / 0.035, 58)
    rpm = (0.08 - 0.035 * t) * 3000 / (0.03 * 6)  # R_a = R_r * 6 * n / 3000
    res = arcvt.evaluate_trace(t, rpm, arcvt.ArcvtParams(horizontal_force_model="vroemen", pivot_distance_m=0.240))
    assert res["max_abs_shift_rate_m_s"] == pytest.approx(0.035, rel=1e-6)
    assert res["max_arm_speed_rad_s"] == pytest.approx(0.64, rel=0.10)  # report Table 5.1; ours 0.69
    assert res["max_actuation_power_w"] == pytest.approx(350, rel=0.25)  # report Table 5.1: 350 W


def test_cli_arcvt(tmp_path, capsys):
    from dyno.cli import main

    tr = tmp_path / "etc.csv"
    tr.write_text("time_s,engine_rpm\n0,800\n1,900\n2,1200\n3,1100\n")
    assert main(["arcvt", "--trace", str(tr), "--vroemen"]) == 0
    assert "Table 3.1" in capsys.readouterr().out
    bad = tmp_path / "p.toml"
    bad.write_text("arm_lenght_m = 0.1\n")
    assert main(["arcvt", "--params", str(bad)]) == 2
