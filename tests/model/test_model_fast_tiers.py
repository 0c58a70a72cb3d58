"""Capstan/Gerbert tier and the closed-form thrust formulary."""

import math
import time

import pytest

from dyno.errors import ConfigError
from dyno.model import capstan, closed_form as cf
from dyno.model.params import TABLE_6_1, TABLE_6_1_POINT, OperatingPoint

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def test_capstan_formulas():
    assert capstan.capstan_tension_ratio(math.pi, 0.4) == pytest.approx(math.exp(0.4 * math.pi))
    beta = math.radians(12)
    assert capstan.virtual_friction_coefficient(0.4, beta) == pytest.approx(0.4 / math.sin(beta))
    # The V-belt wedge always holds more than a flat belt.
    assert capstan.max_tension_ratio(math.pi, 0.4, beta) > capstan.max_tension_ratio(math.pi, 0.4)


def test_capstan_point_is_within_its_own_bound_and_consistent():
    r = capstan.capstan_point(TABLE_6_1, TABLE_6_1_POINT)
    assert not r.gross_slip
    assert r.tight_tension_n - r.slack_tension_n == pytest.approx(18 / r.r_primary_m)
    bound = capstan.max_tension_ratio(r.wrap_primary_rad, 0.4, math.radians(12))
    assert r.tight_tension_n / r.slack_tension_n < bound
    assert 0.99 < r.efficiency_speed < 1.0
    # Axial-force operating point inverts the slack-tension one.
    op2 = OperatingPoint(slack_tension_n=None, primary_axial_force_n=r.axial_force_primary_n)
    r2 = capstan.capstan_point(TABLE_6_1, op2)
    assert r2.slack_tension_n == pytest.approx(100.0, rel=1e-6)


def test_capstan_gross_slip_flagged():
    r = capstan.capstan_point(TABLE_6_1, OperatingPoint(slack_tension_n=1.0, primary_torque_nm=40.0))
    assert r.gross_slip


def test_asymptotic_ratio_solves_eq_15():
    k, k1, k2 = cf.stiffness_numbers(18.71e6, 0.0683, 243.5e3, math.radians(12), 0.4)
    assert k2 < 0 < k < k1
    p = cf.asymptotic_ratio(k, k1, k2, 0.4, math.radians(12), 100 / 364)
    assert 1 / k1 < p < 1 / k


def test_closed_form_rho_zero_limits():
    r = cf.closed_form_point(TABLE_6_1, TABLE_6_1_POINT)
    no_arch = cf.closed_form_point(TABLE_6_1, TABLE_6_1_POINT, arching=False)
    # Arching removes contact, so it lowers both thrusts.
    assert r.axial_force_primary_n < no_arch.axial_force_primary_n
    assert r.axial_force_secondary_n < no_arch.axial_force_secondary_n
    # Driver without shift: uniform penetration at the tight tension (eq 17, rho = 0).
    beta, f = math.radians(12), 0.4
    expected = no_arch.tight_tension_n * math.pi / (2 * math.tan(beta + math.atan(f)))
    assert no_arch.axial_force_primary_n == pytest.approx(expected)
    # Driven thrust lies between the all-slack and all-tight uniform-penetration values.
    lo = no_arch.slack_tension_n * math.pi / (2 * math.tan(beta + math.atan(f)))
    assert lo < no_arch.axial_force_secondary_n < expected
    # The arching deficit follows the conventional formula.
    dtheta = cf.arching_deficit_rad(r.tight_tension_n, r.slack_tension_n, 0.2602, r.r_primary_m)
    assert r.inner_arc_primary_rad == pytest.approx(math.pi - dtheta)


def test_closed_form_thrust_linear_in_tension_level():
    # With rho = 0 and no arching the thrusts are homogeneous of degree 1 in the tensions.
    a = cf.closed_form_point(TABLE_6_1, OperatingPoint(slack_tension_n=100, primary_torque_nm=18), arching=False)
    b = cf.closed_form_point(TABLE_6_1, OperatingPoint(slack_tension_n=200, primary_torque_nm=36), arching=False)
    assert b.axial_force_primary_n == pytest.approx(2 * a.axial_force_primary_n)
    assert b.axial_force_secondary_n == pytest.approx(2 * a.axial_force_secondary_n)


@pytest.mark.parametrize("rho", [-2e-4, 2e-4])
def test_closed_form_with_shift(rho):
    base = cf.closed_form_point(TABLE_6_1, TABLE_6_1_POINT)
    r = cf.closed_form_point(TABLE_6_1, TABLE_6_1_POINT, shift_ratio_primary=rho, shift_ratio_secondary=rho)
    # Closing (rho > 0) adds thrust on the driver, opening removes it (eq 17's second term).
    assert (r.axial_force_primary_n - base.axial_force_primary_n) * rho > 0
    assert math.isfinite(r.axial_force_secondary_n) and r.axial_force_secondary_n > 0


def test_closed_form_axial_force_operating_point_round_trip():
    r = cf.closed_form_point(TABLE_6_1, TABLE_6_1_POINT)
    op = OperatingPoint(slack_tension_n=None, primary_axial_force_n=r.axial_force_primary_n)
    r2 = cf.closed_form_point(TABLE_6_1, op)
    assert r2.slack_tension_n == pytest.approx(100.0, rel=1e-6)
    assert r2.axial_force_secondary_n == pytest.approx(r.axial_force_secondary_n, rel=1e-6)
    # A tiny thrust still has a (barely tensioned) solution: arching eats the wrap.
    tiny = cf.closed_form_point(TABLE_6_1, OperatingPoint(slack_tension_n=None, primary_axial_force_n=1.0))
    assert tiny.slack_tension_n > 0
    with pytest.raises(ConfigError):
        cf.closed_form_point(TABLE_6_1, OperatingPoint(slack_tension_n=None, primary_axial_force_n=1.0), arching=False)


def test_closed_form_is_fast():
    """The closed form is the live tier because it costs a small fraction of the full model's solve: judged as a
    ratio of the two, measured here on the same machine (bench/bench_model.py prints the seconds)."""
    from dyno.model.solution import solve_point

    t0 = time.thread_time()
    solve_point(TABLE_6_1, TABLE_6_1_POINT)
    full_s = time.thread_time() - t0
    t0 = time.thread_time()
    for _ in range(200):
        cf.closed_form_point(TABLE_6_1, TABLE_6_1_POINT)
    closed_s = (time.thread_time() - t0) / 200
    assert closed_s * 20 < full_s, (closed_s, full_s)


def test_capstan_thrust_against_the_full_model(table_6_1):
    """Gerbert's wedge (radial friction where the belt wedges in, none where it slides round) puts the
    capstan tier's thrusts near the full model's; the frictionless wedge everywhere was 2.3x / 1.35x."""
    full = table_6_1.summary["axial_force_n"]
    r = capstan.capstan_point(TABLE_6_1, TABLE_6_1_POINT)
    assert 0.85 < r.axial_force_primary_n / full["primary"] < 1.0     # measured 0.93
    assert 0.7 < r.axial_force_secondary_n / full["secondary"] < 0.8  # measured 0.76
    beta, mu = math.radians(12), 0.4
    frictionless = (r.tight_tension_n * (r.wrap_primary_rad - r.sliding_arc_primary_rad)
                    + (r.tight_tension_n - r.slack_tension_n) * math.sin(beta) / mu) / (2 * math.tan(beta))
    assert frictionless / full["primary"] > 2.2   # the old tier: "2.6x too high" at ratio 1.75
    # the held arc alone is the closed form's rho = 0 driver factor
    held = r.tight_tension_n * (r.wrap_primary_rad - r.sliding_arc_primary_rad) / (2 * math.tan(beta + math.atan(mu)))
    assert r.axial_force_primary_n - held == pytest.approx(
        (r.tight_tension_n - r.slack_tension_n) * math.sin(beta) / mu / (2 * math.tan(beta)))
