"""The simulated CVT's own friction (dyno.sim.cvt_friction): a clutch flank friction per world within its
real range (not the advisor's 0.4), and the ramps'/helix's Coulomb friction as a hysteresis of the shift
(the up-shift later than the frictionless balance, the back-shift earlier, the sheaves still in between)."""

from __future__ import annotations

import pytest

from dyno.sim.cvt_friction import CLUTCH_MU_RANGE, friction_n
from dyno.sim.driven import characterisation_truth
from dyno.sim.physics import RigModel
from dyno.sim.rig_params import RigParams

STOCK = "calibration/tunes/cvtech-stock.toml"


def _model(world, **kw):
    return RigModel(RigParams(cvt_tune_path=STOCK, belt_efficiency_source="loss_model", world_seed=world, **kw),
                    seed=1)


@pytest.mark.quick
def test_the_clutch_friction_is_drawn_per_world_in_its_range_and_used():
    mus = [_model(w).cvt.friction.clutch_friction_coefficient for w in range(6)]
    assert all(CLUTCH_MU_RANGE[0] <= m <= CLUTCH_MU_RANGE[1] for m in mus)
    assert len(set(mus)) == 6 and max(mus) - min(mus) > 0.03
    assert _model(3).cvt.friction == _model(3).cvt.friction  # one rig, one friction
    # the engagement rule uses the world's mu (2 mu r / sin beta), not the advisor's 0.4
    m = _model(2)
    k_04 = _model(2, cvt_clutch_friction_coefficient=0.4).engagement.k_nm_per_n
    assert m.engagement.k_nm_per_n == pytest.approx(k_04 * m.cvt.friction.clutch_friction_coefficient / 0.4)
    # a rig given a value keeps it (and its other frictions' draws)
    g = _model(2, cvt_clutch_friction_coefficient=0.33).cvt.friction
    assert g.clutch_friction_coefficient == 0.33 and g.ramp_friction_frac == m.cvt.friction.ramp_friction_frac


def _speed_where(cvt, x, t_s, target_n):
    """Engine rpm where the imbalance F_p - F_s equals ``target_n`` at travel ``x`` (bisection)."""
    lo, hi = 500.0, 8000.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cvt.force_imbalance_n(mid, t_s, x) < target_n(mid) else (lo, mid)
    return 0.5 * (lo + hi)


def test_up_and_back_shift_differ_and_the_sheaves_hold_in_between():
    cvt = _model(5).cvt
    x, t_s = 0.4, 20.0
    up = _speed_where(cvt, x, t_s, lambda n: friction_n(cvt, n, t_s, x))
    down = _speed_where(cvt, x, t_s, lambda n: -friction_n(cvt, n, t_s, x))
    mid = _speed_where(cvt, x, t_s, lambda n: 0.0)
    assert down + 20.0 < mid < up - 20.0, (down, mid, up)

    def moved(rpm):
        xx = x
        for _ in range(200):
            xx = cvt.shift(xx, rpm, t_s, 0.004)
        return xx - x

    assert moved(up + 30.0) > 1e-3 and moved(down - 30.0) < -1e-3
    assert moved(mid) == 0.0 and moved(up - 15.0) == 0.0 and moved(down + 15.0) == 0.0
    # without friction the same CVT has no band
    cvt.friction = None
    assert abs(moved(mid + 15.0)) > 1e-4


def test_the_truth_is_the_up_shift_and_says_so():
    m = _model(7)
    t = characterisation_truth(m)
    assert t["cvt_friction_true"]["clutch_friction_coefficient"] == m.cvt.friction.clutch_friction_coefficient
    assert "up-shift" in t["truth_figures"]["shift_out_rpm_true"]
    assert "rising" in t["truth_figures"]["engagement_rpm_true"]
    f = _model(7, cvt_ramp_friction_frac=0.0, cvt_helix_friction_frac=0.0, cvt_sheave_friction_n=0.0)
    t0 = characterisation_truth(f)
    # the up-shift needs the friction overcome: later than the frictionless balance; the closing clamp
    # loses the ramps' share: a later engagement
    assert t["shift_out_rpm_true"] > t0["shift_out_rpm_true"] + 15.0
    assert t["engagement_rpm_true"] > t0["engagement_rpm_true"] + 10.0
