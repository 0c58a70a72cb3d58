"""Geometry: round trips, the AR-CVT relation, feasibility errors."""

import math

import pytest

from dyno.errors import ConfigError
from dyno.model import geometry as g

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

PITCH_M, CENTRES_M = 0.8572, 0.214


def test_equal_radius_matches_eq_6_1_and_6_12():
    r = g.equal_radius_m(PITCH_M, CENTRES_M)
    assert r == pytest.approx((PITCH_M - 2 * CENTRES_M) / (2 * math.pi))
    assert g.belt_length_m(r, r, CENTRES_M) == pytest.approx(PITCH_M, rel=1e-14)
    assert g.primary_radius_m(r, PITCH_M, CENTRES_M) == pytest.approx(r, rel=1e-12)


@pytest.mark.parametrize("ratio", [0.5, 0.72, 1.0, 1.3, 1.74, 2.5])
def test_radii_for_ratio_round_trip(ratio):
    r_p, r_s = g.radii_for_ratio(ratio, PITCH_M, CENTRES_M)
    assert r_s / r_p == pytest.approx(ratio, rel=1e-12)
    assert g.belt_length_m(r_p, r_s, CENTRES_M) == pytest.approx(PITCH_M, abs=1e-12)
    assert g.secondary_radius_m(r_p, PITCH_M, CENTRES_M) == pytest.approx(r_s, abs=1e-11)
    assert g.primary_radius_m(r_s, PITCH_M, CENTRES_M) == pytest.approx(r_p, abs=1e-11)


def test_wrap_angles_sum_and_mirror_symmetry():
    r_p, r_s = g.radii_for_ratio(1.5, PITCH_M, CENTRES_M)
    phi_p, phi_s = g.wrap_angles_rad(r_p, r_s, CENTRES_M)
    assert phi_p + phi_s == pytest.approx(2 * math.pi)
    assert phi_p < math.pi < phi_s
    # Swapping the pulleys mirrors the drive: wrap angles swap, length unchanged.
    assert g.wrap_angles_rad(r_s, r_p, CENTRES_M) == pytest.approx((phi_s, phi_p))
    assert g.belt_length_m(r_s, r_p, CENTRES_M) == pytest.approx(g.belt_length_m(r_p, r_s, CENTRES_M))


def test_length_is_monotonic_in_ratio_direction():
    # Larger ratio at fixed belt: primary shrinks, secondary grows.
    rp = [g.radii_for_ratio(r, PITCH_M, CENTRES_M)[0] for r in (0.72, 1.0, 1.74)]
    assert rp[0] > rp[1] > rp[2]


def test_infeasible_inputs_raise_config_error():
    with pytest.raises(ConfigError, match="ratio"):
        g.radii_for_ratio(-1.0, PITCH_M, CENTRES_M)
    with pytest.raises(ConfigError):
        g.tangent_angle_rad(0.01, 0.5, CENTRES_M)
    with pytest.raises(ConfigError):
        g.equal_radius_m(0.3, CENTRES_M)
    with pytest.raises(ConfigError):
        g.primary_radius_m(0.5, PITCH_M, CENTRES_M)


def test_arcvt_centre_distance_satisfies_report_eq_3_1():
    # van Kerkhoven Table 3.1 style: R_r fixed 30 mm, R_a 30..101 mm.
    length_m = g.belt_length_m(0.03, 0.03, 0.279)
    for r_a in (0.03, 0.05, 0.08, 0.101):
        a_h = g.centre_distance_m(0.03, r_a, length_m)
        assert g.arcvt_centre_distance_residual_m(a_h, 0.03, r_a, length_m) == pytest.approx(0, abs=1e-12)
        assert g.variable_radius_m(0.03, a_h, length_m) == pytest.approx(r_a, abs=1e-10)
    # Centre distance falls as the axial pulley radius grows (report Fig 3.2).
    assert g.centre_distance_m(0.03, 0.101, length_m) < g.centre_distance_m(0.03, 0.05, length_m)
    with pytest.raises(ConfigError):
        g.centre_distance_m(0.03, 0.5, length_m)
