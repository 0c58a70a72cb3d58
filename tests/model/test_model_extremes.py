"""Stiff and extreme cases: converge and verify, or fail fast with a DidNotConverge that names the case."""

from dataclasses import replace

import numpy as np
import pytest

from dyno.errors import DidNotConverge, GrossSlip
from dyno.model import boundary, capstan, equations
from dyno.model.params import TABLE_6_1, TABLE_6_1_POINT
from dyno.model.solution import solve_point

TIME_LIMIT_S = 30.0

CASES = {
    "slip_1e-2": (TABLE_6_1, TABLE_6_1_POINT, 1e-2),
    "slip_1e-5": (TABLE_6_1, TABLE_6_1_POINT, 1e-5),
    "EI_0.01": (TABLE_6_1.with_belt(bending_stiffness_nm2=0.01), TABLE_6_1_POINT, 1e-4),
    "EI_0.1": (TABLE_6_1.with_belt(bending_stiffness_nm2=0.1), TABLE_6_1_POINT, 1e-4),
    "EI_1.0": (TABLE_6_1.with_belt(bending_stiffness_nm2=1.0), TABLE_6_1_POINT, 1e-4),
    # A light belt: 30 N of slack carries 2 N*m (the spans arch far off the pulleys: bending length
    # sqrt(EI/T) ~ 90 mm).  At 10 N it is past gross slip even at 2 N*m (test below).
    "slack_30N_2Nm": (TABLE_6_1, replace(TABLE_6_1_POINT, slack_tension_n=30.0, primary_torque_nm=2.0), 1e-4),
    "ratio_2.0": (TABLE_6_1, replace(TABLE_6_1_POINT, ratio=2.0), 1e-4),
    "ratio_0.6": (TABLE_6_1, replace(TABLE_6_1_POINT, ratio=0.6), 1e-4),
    "rpm_7600": (TABLE_6_1, replace(TABLE_6_1_POINT, primary_speed_rpm=7600.0), 1e-4),
    "beta_8": (TABLE_6_1.with_sheave_angle(8.0), TABLE_6_1_POINT, 1e-4),
    "beta_16": (TABLE_6_1.with_sheave_angle(16.0), TABLE_6_1_POINT, 1e-4),
}


def verify(sol):
    raw = sol.raw
    assert raw.residual_max <= raw.tol
    bc = boundary.make_bc(raw.case)(raw.y[:, 0], raw.y[:, -1], raw.p)
    assert np.max(np.abs(bc)) < raw.tol
    s = sol.summary
    assert 0 < s["efficiency"]["overall"] < 1
    assert s["axial_force_n"]["primary"] > 0 and s["axial_force_n"]["secondary"] > 0
    for i_t, k_phi in ((equations.P_T, equations.K_PHIP), (equations.S_T, equations.K_PHIS)):
        tension = raw.y[i_t] * 100
        assert tension.min() > 0
        assert tension.max() / tension.min() < capstan.max_tension_ratio(raw.p[k_phi], raw.case.mu, raw.case.beta_rad)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(CASES))
def test_extreme_case(name, table_6_1_rounded):
    params, op, slip = CASES[name]
    # Every case here has a steady solution: a DidNotConverge or GrossSlip is a regression (no xfail).
    sol = solve_point(params, op, slip_threshold_m_s=slip, guess=table_6_1_rounded, friction_corner=0.2,
                      time_limit_s=TIME_LIMIT_S, max_nodes=3000)
    verify(sol)
    assert max(sol.summary["balance"].values()) < 5e-3, sol.summary["balance"]


@pytest.mark.slow
@pytest.mark.parametrize("torque_nm", [2.0, 18.0])
def test_slack_10N_is_gross_slip_and_says_so(table_6_1_rounded, torque_nm):
    """10 N of slack cannot carry 2 N*m, let alone 18: on the way down in tension (torque first, tension
    last) a pulley reaches its capstan bound near 18-19 N (its wrap shrinks as the spans arch), and the
    target asks more of the belt than that point, so there is no steady solution.  The answer is the
    state, not a number (a solution beyond the bound is rejected) and not "did not converge"."""
    op = replace(TABLE_6_1_POINT, slack_tension_n=10.0, primary_torque_nm=torque_nm)
    with pytest.raises(GrossSlip) as info:
        solve_point(TABLE_6_1, op, guess=table_6_1_rounded, friction_corner=0.2, time_limit_s=60.0)
    assert not isinstance(info.value, DidNotConverge)  # a physical state, not a numerical failure
    msg = str(info.value)
    assert msg.startswith(f"gross slip: the belt cannot transmit {torque_nm:g} N*m")
    assert "T_slack=10 N" in msg and "capstan bound" in msg


def test_infeasible_geometry_is_a_config_error():
    from dyno.errors import ConfigError

    with pytest.raises(ConfigError):
        solve_point(TABLE_6_1, replace(TABLE_6_1_POINT, ratio=1e4))  # radii below 10 mm
    with pytest.raises(ConfigError):
        solve_point(TABLE_6_1, TABLE_6_1_POINT, variant="nonsense")


@pytest.mark.slow
@pytest.mark.parametrize("ratio, torque_nm, anchors_fail", [(0.72, 3.0, False), (2.4, 10.0, False),
                                                            (0.72, 3.0, True)])
def test_a_heavy_clamp_at_a_light_torque_solves_cold(table_6_1, monkeypatch, ratio, torque_nm, anchors_fail):
    """2,000 N of primary clamp at 3-10 N*m: with a finite-difference bc Jacobian the geometric guess failed at
    every clamp-force anchor (every such case of a 4-ratio grid did, before the slack-span anchor); with the
    exact one the equal-radii anchor passes, and the slack-span anchor (the last resort) is driven here by
    making the others fail.  Cold, by whichever anchor, it converges -- to the same solution a warm start from
    the thesis's point finds (one steady state, not an artefact of the path)."""
    op = replace(TABLE_6_1_POINT, ratio=ratio, primary_torque_nm=torque_nm, slack_tension_n=None,
                 primary_axial_force_n=2000.0)
    if anchors_fail:
        # Since the exact bc Jacobian the equal-radii anchor passes on these cases; the last resort is driven here
        # by a geometric guess that is useless at any clamp-force condition (NaN states), as it was before
        from dyno.model import bvp
        from dyno.model.guess import initial_guess as real_guess

        def guess(case, n):
            t, y, p = real_guess(case, n)
            return (t, y * np.nan, p) if case.bc == "primary_axial_force" else (t, y, p)

        monkeypatch.setattr(bvp, "initial_guess", guess)
    cold = solve_point(TABLE_6_1, op, slip_threshold_m_s=1e-3, time_limit_s=60.0)
    verify(cold)
    path = " ".join(h.what for h in cold.raw.history)
    assert "slack span 100 N" in path or "geometric guess at equal radii" in path, path  # an anchor, not the guess
    if anchors_fail:
        assert "slack span 100 N" in path, path
    assert cold.summary["axial_force_n"]["primary"] == pytest.approx(2000.0, rel=1e-3)
    warm = solve_point(TABLE_6_1, op, slip_threshold_m_s=1e-3, guess=table_6_1, time_limit_s=60.0)
    for k in ("speed", "torque", "overall"):
        assert cold.summary["efficiency"][k] == pytest.approx(warm.summary["efficiency"][k], abs=1e-4), k
    assert cold.summary["axial_force_n"]["secondary"] == pytest.approx(warm.summary["axial_force_n"]["secondary"],
                                                                       rel=1e-3)
