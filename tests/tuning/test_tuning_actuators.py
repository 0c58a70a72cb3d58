"""Actuator relations pinned to their source equations.

Messick 2018 eqs. 9.2-9.3 (sliding flyweights, primary spring); Sorge &
Cammalleri eqs. 11 (torque split), 20-21 (roller on track), 22 (secondary).
"""

import math
from pathlib import Path

import numpy as np
import pytest

from dyno.tuning import actuators as act
from dyno.tuning.geometry import open_belt_length_m, secondary_radius_for_primary_m
from dyno.tuning.tune import RollerTrack, load_tune

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

ROOT = Path(__file__).resolve().parents[2]
TUNE = load_tune(ROOT / "calibration/tunes/cvtech-stock.toml")


def test_belt_length_equal_radii_and_thesis_one_to_one():
    # L = 2C + 2 pi r at 1:1; Messick Table 6.1: L=857.2 mm, C=214 mm -> r=68.3 mm.
    assert open_belt_length_m(0.05, 0.05, 0.2) == pytest.approx(0.4 + 2 * math.pi * 0.05)
    assert secondary_radius_for_primary_m(0.0683, 0.8572, 0.214) == pytest.approx(0.0683, abs=2e-4)
    rp = np.linspace(0.03, 0.09, 7)
    rs = secondary_radius_for_primary_m(rp, 0.8572, 0.214)
    assert np.allclose(open_belt_length_m(rp, rs, 0.214), 0.8572, atol=1e-10)


def test_messick_eq_9_3_spring_950_n_at_full_shift():
    # Eq. 9.3: spring = 950 - 18200 * 2 tan(beta) * (0.093 - R_p).
    for rp in (0.032, 0.06, 0.093):
        expect = 950 - 18200 * 2 * math.tan(math.radians(12)) * (0.093 - rp)
        assert act.primary_spring_force_n(TUNE, rp) == pytest.approx(expect, rel=1e-12)


def test_messick_eq_9_2_sliding_mass_force_by_hand():
    # Eq. 9.2: F = 3 m r (dD_R/dD_A) w^2 on a linear ramp (2-point profile).
    from dyno.tuning.tune import FlyweightProfile

    prof = FlyweightProfile(3, 0.228, (0.0, 0.02), (0.04, 0.05))
    w = 3000 * math.pi / 30
    z = 0.01
    expect = 3 * 0.228 * 0.045 * 0.5 * w ** 2
    assert act.sliding_mass_force_n(prof, 3000, z) == pytest.approx(expect, rel=1e-12)


def test_primary_net_force_is_flyweights_minus_spring_and_scales_with_w2():
    rp = 0.06
    f1 = act.primary_centrifugal_force_n(TUNE, 2000, rp)
    f2 = act.primary_centrifugal_force_n(TUNE, 4000, rp)
    assert f2 == pytest.approx(4 * f1)
    assert act.primary_axial_force_n(TUNE, 3000, rp) == pytest.approx(
        act.primary_centrifugal_force_n(TUNE, 3000, rp) - act.primary_spring_force_n(TUNE, rp))
    # inverse in speed
    f = act.primary_axial_force_n(TUNE, 3123.0, rp)
    assert act.primary_speed_for_force_rpm(TUNE, f, rp) == pytest.approx(3123.0)


def _roller():
    # A track circle through the roller at zero travel (consistent geometry).
    r_c_min, r_t0, r_t = 0.030, 0.020, 0.025
    z_t0 = -math.sqrt(r_t ** 2 - (r_c_min - r_t0) ** 2)
    return RollerTrack(0.0426, r_c_min, r_t0, z_t0, r_t, 60.0)


def test_sorge_eq_20_roller_stays_on_both_tracks():
    roller = _roller()
    dz = np.linspace(0.0, 0.01, 11)
    dr, _ = act.roller_position(roller, dz)
    assert dr[0] == pytest.approx(0.0, abs=1e-12)
    cot_f = 1 / math.tan(math.radians(roller.fixed_ramp_angle_deg))
    lhs = (roller.roller_radius_min_m + dr - roller.track_centre_radius_m) ** 2 + (
        dr * cot_f - roller.track_centre_axial_m - dz) ** 2
    assert np.allclose(lhs, roller.track_radius_m ** 2, atol=1e-12)
    assert np.all(np.diff(dr) > 0)  # rollers climb outwards as the sheave closes


def test_sorge_eq_21_equals_virtual_work_of_eq_20():
    # Eq. 21 is the frictionless roller balance; it must equal the virtual
    # work form m w^2 r_c d(r_c)/dz obtained by differentiating eq. 20.
    roller = _roller()
    dz = np.linspace(0.001, 0.008, 8)
    h = 1e-7
    drp, _ = act.roller_position(roller, dz + h)
    drm, _ = act.roller_position(roller, dz - h)
    dr, _ = act.roller_position(roller, dz)
    w = 4000 * math.pi / 30
    virtual = roller.total_mass_kg * w ** 2 * (roller.roller_radius_min_m + dr) * (drp - drm) / (2 * h)
    assert np.allclose(act.roller_track_force_n(roller, 4000, dz), virtual, rtol=1e-5)


def test_sorge_eq_22_steady_state_by_hand():
    # Steady state: M_s = M/2; F = F0 + K z + (2 (M/2 + M_t) / d) tan(delta).
    rs = 0.07
    M = 30.0
    z = 2 * math.tan(math.radians(12)) * (act.secondary_radius_closed_m(TUNE) - rs)
    s, h = TUNE.secondary_spring, TUNE.helix
    tan_d = math.tan(math.radians(h.angle_from_axis_deg))
    m_t = s.torsion_preload_nm + s.torsion_rate_nm_per_rad * z * tan_d / h.radius_m
    expect = s.preload_n + s.rate_n_per_m * z + (2 * (M / 2 + m_t) / (2 * h.radius_m)) * tan_d
    assert act.secondary_axial_force_n(TUNE, M, rs) == pytest.approx(expect, rel=1e-12)


def test_sorge_eq_11_split_sign_and_published_coefficients():
    # Eq. 11 with a_open=-0.9, b_open=0.04, a_close=1.85, b_close=0.03: while
    # the driven pulley opens (rho<0) the sliding half carries MORE than half
    # the torque; while closing (rho>0) it carries LESS.
    split = TUNE.torque_split
    assert (split.a_opening, split.b_opening, split.a_closing, split.b_closing) == (-0.9, 0.04, 1.85, 0.03)
    ta = math.tan(math.radians(12))
    args = dict(torque_nm=30.0, axial_force_n=1500.0, radius_m=0.06, tan_alpha_=ta)
    x = 2 * 0.06 * 1500 * ta / 30 - math.sin(math.radians(12)) / 0.4
    opening = act.torque_fraction_sliding(split, closing=False, shift_speed_ratio=2e-4, belt_exit_strain=1e-3, **args)
    closing = act.torque_fraction_sliding(split, closing=True, shift_speed_ratio=2e-4, belt_exit_strain=1e-3, **args)
    assert opening == pytest.approx(0.5 + (-0.9 * -0.2 + 0.04) * x ** 1.5)
    assert closing == pytest.approx(0.5 - (1.85 * 0.2 + 0.03) * x ** 1.5)
    assert opening > 0.5 > closing
    assert act.torque_fraction_sliding(split, closing=None, **args) == 0.5
    # gross slip end (x <= 0): equal split
    low = act.torque_fraction_sliding(split, 30.0, 10.0, 0.06, ta, closing=True)
    assert low == pytest.approx(0.5)


def test_helix_torque_feedback_sign_eq_22():
    # More resistant torque -> more secondary clamp (the paper's point of the
    # helix), in every phase; and opening clamp > steady > closing clamp.
    rs = 0.06
    torques = np.linspace(5, 60, 12)
    for closing in (None, True, False):
        f = act.secondary_axial_force_n(TUNE, torques, rs, closing=closing)
        assert np.all(np.diff(f) > 0)
    f_open = act.secondary_axial_force_n(TUNE, 40.0, rs, closing=False)
    f_steady = act.secondary_axial_force_n(TUNE, 40.0, rs)
    f_close = act.secondary_axial_force_n(TUNE, 40.0, rs, closing=True)
    assert f_open > f_steady > f_close


def test_secondary_eq_22_self_consistent_with_eq_11():
    rs, M = 0.05, 25.0
    for closing in (True, False):
        F = act.secondary_axial_force_n(TUNE, M, rs, closing=closing)
        frac = act.torque_fraction_sliding(TUNE.torque_split, M, F, rs, act.tan_alpha(TUNE), closing)
        rebuilt = (act.secondary_spring_force_n(TUNE, rs)
                   + act._helix_force_n(TUNE, frac * M + act.secondary_torsion_torque_nm(TUNE, rs)))
        assert F == pytest.approx(float(rebuilt), rel=1e-9)


def test_reverse_torque_lifts_helix_rollers():
    rs = 0.06
    f_spring = act.secondary_spring_force_n(TUNE, rs)
    assert act.secondary_axial_force_n(TUNE, -500.0, rs) == pytest.approx(float(f_spring))
