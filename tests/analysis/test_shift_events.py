"""Pure analysis of the characterisations on synthetic data with known answers."""

import math

import numpy as np
import pytest

from dyno.analysis import coastdown as cd
from dyno.analysis import shift_events as se

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def _edges(t_s, omega_rad_s, phase=0.3):
    """Edge times (us) of a shaft with speed samples ``omega`` on the grid ``t``: one per revolution."""
    theta = phase + np.concatenate([[0.0], np.cumsum(0.5 * (omega_rad_s[1:] + omega_rad_s[:-1]) * np.diff(t_s))])
    k = np.arange(1, int(theta[-1] // (2 * math.pi)) + 1) * 2 * math.pi
    return (np.interp(k, theta, t_s) * 1e6).astype(np.int64)


def test_engagement_extrapolates_the_start_of_the_secondary():
    t = np.arange(0.0, 20.0, 1e-4)
    n_e = 1800.0 + 25.0 * t  # engine ramp, rpm
    t0 = 12.0  # the secondary starts here (engine 2100 rpm)
    w_s = np.where(t > t0, 60.0 * (t - t0) ** 2, 0.0)
    w_s = np.minimum(w_s, n_e * math.pi / 30 / 2.4)  # then locked at ratio 2.4
    p = _edges(t, n_e * math.pi / 30)
    s = _edges(t, w_s)
    eng = se.engagement(p, s, 0, low_ratio_guess=2.4)
    assert eng["engagement_periods"] >= 3
    assert abs(eng["engagement_rpm"] - 2100.0) < 5.0
    assert eng["engagement_rpm_ci95"] < 20.0


def test_ratio_events_find_lock_shift_out_and_full_shift():
    t = np.arange(0.0, 40.0, 1e-4)
    n_e = 2000.0 + 25.0 * t
    ratio = np.where(n_e < 2500, 2.4, np.maximum(0.75, 2.4 - (n_e - 2500) * 0.02))  # shift-out at 2500 rpm
    w_s = np.where(t > 1.0, n_e * math.pi / 30 / ratio, 0.0)
    p = _edges(t, n_e * math.pi / 30)
    s = _edges(t, w_s)
    ev = se.ratio_events(se.ratio_series(p, s, 0, int(40e6)), 1.2e6)
    assert ev["low_ratio"] == pytest.approx(2.4, rel=2e-3)
    assert abs(ev["shift_out_rpm"] - 2500.0) < 30.0
    assert ev["full_shift_ratio"] == pytest.approx(0.75, rel=2e-3)
    assert ev["full_shift_ratio_ci95"] < 0.01


def test_coast_down_fit_recovers_a_known_loss():
    a, b, c, j = 0.3, 5e-4, 1.5e-6, 0.025
    dt = 1e-4
    t = np.arange(0.0, 30.0, dt)
    w = np.empty_like(t)
    w[0] = 100.0
    for i in range(1, t.size):  # J dw/dt = -(a + b w + c w^2), until rest
        w[i] = max(0.0, w[i - 1] - dt * (a + b * w[i - 1] + c * w[i - 1] ** 2) / j)
    s = _edges(t, w)
    dec = cd.decelerations(s, 0)
    keep = dec["omega_rad_s"] > 6.0
    fit = cd.fit_loss(dec["omega_rad_s"][keep], dec["alpha_rad_s2"][keep], j, 0.03)
    true = a + b * np.array(fit["rpm_grid"]) * math.pi / 30 + c * (np.array(fit["rpm_grid"]) * math.pi / 30) ** 2
    assert np.max(np.abs(np.array(fit["torque_nm"]) / true - 1)) < 0.01
    # the inertia's 3 % is the dominant (systematic) part of the band
    assert fit["torque_sys95_nm"][0] == pytest.approx(0.06 * fit["torque_nm"][0])
    with pytest.raises(ValueError, match="at least 6"):
        cd.fit_loss([1.0, 2.0], [-1.0, -1.0], j)


def test_flatness_interval_carries_each_rows_own_interval():
    """Three rows that happen to line up leave the fit a tiny interval; the rows' own shift-out intervals,
    carried through the slope's weights, keep the stated one honest (a Monte Carlo of the rows' errors)."""
    loads, ci95 = np.array([0.66, 3.34, 7.72]), np.array([5.0, 14.0, 32.0])
    truth = 2720.0 + 44.0 * loads
    lined_up = se.flatness(loads, truth + 0.01 * loads, ci95)
    assert lined_up["slope_ci95_rpm_per_nm"] > 10 * se.flatness(loads, truth + 0.01 * loads)["slope_ci95_rpm_per_nm"]
    rng = np.random.default_rng(7)
    inside = 0
    for _ in range(400):
        y = truth + rng.normal(0.0, ci95 / 1.96)
        f = se.flatness(loads, y, ci95)
        inside += abs(f["slope_rpm_per_nm"] - 44.0) <= f["slope_ci95_rpm_per_nm"]
    assert inside >= 0.93 * 400  # (95 % at least: the larger of the two intervals)
    # two rows: no residuals, the rows' interval alone; without row intervals, none
    assert math.isfinite(se.flatness(loads[:2], truth[:2], ci95[:2])["slope_ci95_rpm_per_nm"])
    assert math.isnan(se.flatness(loads[:2], truth[:2])["slope_ci95_rpm_per_nm"])
