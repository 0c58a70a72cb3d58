"""Engagement, lock-up, shift-out and full-shift ratio from a slow throttle ramp (pure, no I/O).

Input: the Hall edge times (device microseconds) of the primary (engine) and the
secondary over a ramp that starts with the engine at idle and the secondary at
rest, with a light, constant load.  Definitions (docs/control.md, "Characterisation"):

* ``engagement_rpm`` -- engine rpm at which the secondary starts to turn.  The
  secondary's first revolutions are slow and sparse (one edge per revolution), so
  the start is extrapolated: while the belt slips, the torque the primary passes
  grows about linearly with time on a ramp (the clamp grows with n^2), the
  secondary's acceleration with it, so its speed grows as (t - t0)^2 and its square
  root is linear in time.  ``t0`` is the zero of a straight-line fit of sqrt(rpm)
  over the slipping periods; its 95 % interval comes from the fit (Student t).
* ``lockup_rpm`` -- engine rpm at which the belt stops slipping: the speed ratio
  first comes within ``lock_tol`` of its low-gear plateau.
* ``shift_out_rpm`` -- engine rpm at which the ratio starts to fall from the
  plateau.  Found where it is below ``plateau (1 - shift_tol)`` for good, then taken
  back to the onset: the sheave moves at a speed that grows with the force imbalance,
  which grows linearly on a ramp, so the ratio's departure grows as (t - t0)^2 and
  ``t0`` is the zero of a line through its square root (its first 3 %), as for
  engagement; the 95 % interval from that fit.
* ``full_shift_ratio`` -- the speed ratio (rpm_primary / rpm_secondary, creep
  included, as in the points) on the plateau at the high stop, with its 95 % interval
  from batch means.

Speeds over sliding windows are mean speeds by edge count (immune to the firing
ripple); each window's ratio is the ratio of the two.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from dyno.acquisition.rpm import rpm_per_period


def _t975(dof: int) -> float:
    return float(stats.t.ppf(0.975, max(1, dof)))


def _sqrt_root(x_s: np.ndarray, y: np.ndarray) -> tuple[float, float, int]:
    """Zero of a straight line through sqrt(y) against time: a quantity growing as (t - t0)^2 from t0.

    Returns ``(t0, sd_t0, n)`` (NaN when the fit cannot say); ``sd_t0`` by the delta method on the
    line's covariance.
    """
    n = int(x_s.size)
    if n < 3:
        return math.nan, math.nan, n
    z = np.sqrt(np.maximum(y, 0.0))
    fit = stats.linregress(x_s, z)
    if not fit.slope > 0:
        return math.nan, math.nan, n
    resid = z - (fit.intercept + fit.slope * x_s)
    s2 = float(resid @ resid) / max(1, n - 2)
    sxx = float(((x_s - x_s.mean()) ** 2).sum())
    var_a = s2 * (1.0 / n + x_s.mean() ** 2 / sxx)
    var_b = s2 / sxx
    cov_ab = -x_s.mean() * s2 / sxx
    g_a, g_b = -1.0 / fit.slope, fit.intercept / fit.slope ** 2
    sd = math.sqrt(max(0.0, g_a * g_a * var_a + g_b * g_b * var_b + 2 * g_a * g_b * cov_ab))
    return -fit.intercept / fit.slope, sd, n


def rpm_at(edges_us: np.ndarray, t_us: float, half_window_us: float = 150_000) -> float:
    """Mean rpm by count over ``t +- half_window`` (NaN with fewer than two edges)."""
    e = edges_us[(edges_us >= t_us - half_window_us) & (edges_us <= t_us + half_window_us)]
    if e.size < 2:
        return math.nan
    return 60e6 * (e.size - 1) / float(e[-1] - e[0])


def ratio_series(p_edges_us, s_edges_us, t0_us: int, t1_us: int, window_s: float = 0.3,
                 step_s: float = 0.1) -> dict:
    """Sliding-window mean speeds and their ratio: arrays ``t_us, rpm_primary, rpm_secondary, ratio``."""
    p = np.asarray(p_edges_us, dtype=np.int64)
    s = np.asarray(s_edges_us, dtype=np.int64)
    half = window_s * 1e6 / 2
    ts = np.arange(t0_us + half, t1_us - half, step_s * 1e6)
    rp = np.array([rpm_at(p, t, half) for t in ts])
    rs = np.array([rpm_at(s, t, half) for t in ts])
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(rs > 0, rp / rs, np.nan)
    return {"t_us": ts, "rpm_primary": rp, "rpm_secondary": rs, "ratio": ratio}


def engagement(p_edges_us, s_edges_us, t_from_us: int, *, max_periods: int = 12,
               low_ratio_guess: float | None = None) -> dict:
    """Engine rpm at which the secondary starts to turn (see the module docstring).

    Uses the secondary periods from its first edge after ``t_from_us`` while it still
    slips (its ratio 5 % above the locked ``low_ratio_guess``, when given),
    at most ``max_periods``.
    """
    p = np.asarray(p_edges_us, dtype=np.int64)
    s = np.asarray(s_edges_us, dtype=np.int64)
    s = s[s > t_from_us]
    out = {"engagement_rpm": math.nan, "engagement_rpm_ci95": math.nan, "engagement_t_us": None,
           "engagement_periods": 0}
    if s.size < 2:
        return out
    t_end, rpm = rpm_per_period(s)
    t_mid = t_end - 30e6 / rpm  # the middle of each period
    keep = np.ones(rpm.size, dtype=bool)
    if low_ratio_guess:
        rp_here = np.array([rpm_at(p, t) for t in t_mid])
        keep = rpm < rp_here / (low_ratio_guess * 1.05)  # still slipping: 5 % above the locked ratio
        # only the first run of slipping periods
        if not keep[0]:
            keep[:] = False
        else:
            first_bad = np.argmin(keep) if not keep.all() else keep.size
            keep[first_bad:] = False
    n = int(min(keep.sum(), max_periods))
    if n >= 3:
        x = (t_mid[:n] - t_mid[0]) / 1e6
        t0, sd_t0, _ = _sqrt_root(x, rpm[:n])
        if math.isfinite(t0):
            # never later than the first edge (the shaft turned before it)
            t0_us = min(float(t_mid[0] + t0 * 1e6), float(s[0]))
            r0 = rpm_at(p, t0_us, 250_000)
            out.update(engagement_rpm=r0, engagement_t_us=int(t0_us), engagement_periods=n,
                       engagement_rpm_ci95=abs(_ramp_rate(p, t0_us)) * _t975(n - 2) * sd_t0 + _rpm_noise(p, t0_us))
            return out
    # too few slipping periods: the first edge bounds it (the shaft turned before it)
    r1 = rpm_at(p, float(s[0]), 250_000)
    out.update(engagement_rpm=r1, engagement_t_us=int(s[0]), engagement_periods=n,
               engagement_rpm_ci95=math.nan)
    return out


def _ramp_rate(p: np.ndarray, t_us: float) -> float:
    """Engine speed's rate of change (rpm/s) over +-1 s."""
    return (rpm_at(p, t_us + 1e6, 250_000) - rpm_at(p, t_us - 1e6, 250_000)) / 2.0


def _rpm_noise(p: np.ndarray, t_us: float) -> float:
    """95 % half-width of a 0.5 s by-count engine speed (edge-timing jitter is negligible;
    the firing ripple averages out over whole revolution pairs): 2 sd of the per-period
    scatter over sqrt(periods)."""
    e = p[(p >= t_us - 250_000) & (p <= t_us + 250_000)]
    if e.size < 4:
        return 0.0
    _, r = rpm_per_period(e)
    return 2.0 * float(r.std()) / math.sqrt(r.size)


def ratio_events(series: dict, t_engaged_us: float, *, lock_tol: float = 0.01, shift_tol: float = 0.003,
                 high_tol: float = 0.01) -> dict:
    """Lock-up, shift-out and full-shift ratio from :func:`ratio_series` after engagement."""
    t = series["t_us"]
    rp, ratio = series["rpm_primary"], series["ratio"]
    out = {k: math.nan for k in ("lockup_rpm", "lockup_rpm_ci95", "shift_out_rpm", "shift_out_rpm_ci95",
                                  "full_shift_ratio", "full_shift_ratio_ci95", "low_ratio", "low_ratio_ci95")}
    ok = (t > t_engaged_us) & np.isfinite(ratio)
    t, rp, ratio = t[ok], rp[ok], ratio[ok]
    if ratio.size < 10:
        return out
    # Low-gear plateau: after lock-up the ratio sits on the low stop; take the most
    # common value among the upper ratios (the mode of a histogram is robust to the
    # slipping start and the shift).
    hi_part = ratio[ratio > np.nanmin(ratio) * 1.5] if np.nanmax(ratio) > 1.5 * np.nanmin(ratio) else ratio
    hist, edges = np.histogram(hi_part[hi_part < np.percentile(hi_part, 99)], bins=200)
    k = int(np.argmax(hist))
    guess = 0.5 * (edges[k] + edges[k + 1])
    near = np.abs(ratio - guess) < 0.01 * guess
    low = float(np.median(ratio[near]))
    out["low_ratio"] = low
    idx_near = np.flatnonzero(near)
    out["low_ratio_ci95"] = _t975(idx_near.size - 1) * float(ratio[near].std(ddof=1)) / math.sqrt(
        max(1, idx_near.size / 3)) if idx_near.size > 3 else math.nan  # windows overlap 3x
    locked = np.flatnonzero(ratio <= low * (1 + lock_tol))
    if locked.size:
        i = int(locked[0])
        out["lockup_rpm"] = float(rp[i])
        out["lockup_rpm_ci95"] = _step_ci(rp, i)
    # Shift-out: the last time the ratio was still on the plateau before it falls for good.
    below = ratio < low * (1 - shift_tol)
    if below.any():
        j = int(np.flatnonzero(below)[0])
        # fell for good: stays below from j on for at least 1 s of windows
        while j < ratio.size and not below[j:j + 10].all():
            nxt = np.flatnonzero(below[j + 1:])
            if not nxt.size:
                j = ratio.size
                break
            j = j + 1 + int(nxt[0])
        if j < ratio.size:
            # The threshold crossing comes late: the sheave starts moving as soon as the forces cross,
            # at a speed that grows with the imbalance, so the ratio's departure grows as (t - t0)^2.
            # t0 is the zero of sqrt(departure) over its first few percent (as for engagement).
            out["shift_out_rpm"] = float(rp[j])
            out["shift_out_t_us"] = int(t[j])
            out["shift_out_rpm_ci95"] = _step_ci(rp, j)
            dev = (low - ratio) / low
            sel = (t >= t[j] - 2e6) & (t <= t[j] + 1.5e6) & (dev > 0.0005) & (dev < 0.03)
            t0, sd_t0, n_fit = _sqrt_root(t[sel] / 1e6, dev[sel])
            if math.isfinite(t0) and t[j] - 3e6 < t0 * 1e6 <= t[j]:
                k = int(np.argmin(np.abs(t - t0 * 1e6)))
                rate = (rp[min(k + 10, rp.size - 1)] - rp[max(k - 10, 0)]) / ((t[min(k + 10, rp.size - 1)]
                                                                             - t[max(k - 10, 0)]) / 1e6)
                out["shift_out_rpm"] = float(np.interp(t0 * 1e6, t, rp))
                out["shift_out_t_us"] = int(t0 * 1e6)
                out["shift_out_rpm_ci95"] = abs(rate) * _t975(n_fit - 2) * sd_t0 + _step_ci(rp, k)
            # Full shift: the lowest ratio's plateau after the shift
            after = ratio[j:]
            r_min = float(np.percentile(after, 2))
            plateau = after[after <= r_min * (1 + high_tol)]
            if plateau.size >= 5:
                out["full_shift_ratio"] = float(np.median(plateau))
                # windows overlap (step < window): count them as independent per window length
                n_eff = max(2.0, plateau.size / 3)
                out["full_shift_ratio_ci95"] = _t975(int(n_eff) - 1) * float(plateau.std(ddof=1)) / math.sqrt(n_eff)
                out["full_shift_windows"] = int(plateau.size)
    return out


def _step_ci(rp: np.ndarray, i: int) -> float:
    """Half the engine-speed change between neighbouring windows: the detection's time resolution."""
    lo, hi = max(0, i - 1), min(rp.size - 1, i + 1)
    return 0.5 * abs(float(rp[hi]) - float(rp[lo]))


def flatness(loads_nm, shift_out_rpm, shift_out_ci95_rpm=None) -> dict:
    """Shift-out rpm against the secondary load: the straight line's slope (rpm per N m) and its 95 %
    half-width, and the spread (max - min) -- a flat shift-out holds one engine speed whatever the load.

    The half-width is the larger of the fit's (its residuals, n - 2 dof) and the rows' own (each shift-out's
    ``shift_out_ci95_rpm`` carried through the slope's weights): three rows leave one degree of freedom, and
    rows that happen to line up say nothing of how well each was measured."""
    x = np.asarray(loads_nm, dtype=float)
    y = np.asarray(shift_out_rpm, dtype=float)
    u = np.full(x.shape, np.nan) if shift_out_ci95_rpm is None else np.asarray(shift_out_ci95_rpm, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y, u = x[ok], y[ok], u[ok]
    out = {"n": int(x.size), "spread_rpm": float(y.max() - y.min()) if y.size else math.nan,
           "slope_rpm_per_nm": math.nan, "slope_ci95_rpm_per_nm": math.nan}
    if x.size >= 2 and np.ptp(x) > 0:
        fit = stats.linregress(x, y)
        out["slope_rpm_per_nm"] = float(fit.slope)
        ci = _t975(x.size - 2) * float(fit.stderr) if x.size >= 3 else math.nan
        if np.all(np.isfinite(u)):
            dx = x - x.mean()
            rows = float(np.sqrt(np.sum((dx / np.sum(dx * dx) * u) ** 2)))  # each row's ci95 through its weight
            ci = rows if not math.isfinite(ci) else max(ci, rows)
        out["slope_ci95_rpm_per_nm"] = ci
    return out
