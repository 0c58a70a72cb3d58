"""Shaft speed from Hall edge times (pure numpy).

Two estimators, both from one pulse per revolution:

* per period: ``rpm_i = 60e6 / (t_i - t_{i-1})`` at each edge (fast, noisy:
  a 4-stroke single cylinder's speed ripples within a revolution pair);
* by count over a window: ``rpm = 60e6 * (n - 1) / (t_last - t_first)`` over the
  ``n`` edges inside it: the mean speed, insensitive to firing ripple;
* by adjacent pairs: the same mean, but only over periods between *adjacent*
  edges -- a period that spans lost events (``gap``) is left out, never spread
  over (a window with lost edges would otherwise read low by the loss fraction).

A Hall sensor that stops means the shaft stopped (or the sensor died): after
``stale_factor`` times the last period, or ``timeout_us``, with no edge, the
speed is 0, not the last value.
"""

from __future__ import annotations

import numpy as np


def rpm_per_period(t_us) -> tuple[np.ndarray, np.ndarray]:
    """Edge times -> (time of each period's end, rpm over that period)."""
    t = np.asarray(t_us, dtype=np.int64)
    if t.size < 2:
        return t[:0], np.zeros(0)
    dt = np.diff(t)
    ok = dt > 0
    return t[1:][ok], 60e6 / dt[ok]


def rpm_by_count(t_us, t_start_us: int | None = None, t_end_us: int | None = None) -> tuple[float, int]:
    """Mean rpm from the edges within ``[t_start_us, t_end_us]``; returns (rpm, periods).

    Returns ``(nan, 0)`` with fewer than two edges.
    """
    t = np.asarray(t_us, dtype=np.int64)
    if t_start_us is not None or t_end_us is not None:
        lo = -np.iinfo(np.int64).max if t_start_us is None else t_start_us
        hi = np.iinfo(np.int64).max if t_end_us is None else t_end_us
        t = t[(t >= lo) & (t <= hi)]
    if t.size < 2 or t[-1] <= t[0]:
        return float("nan"), 0
    return 60e6 * (t.size - 1) / float(t[-1] - t[0]), int(t.size - 1)


def rpm_by_pairs(t_us, gap=None) -> tuple[float, int]:
    """Mean rpm over the periods between adjacent edges; ``gap[i]`` true means the
    period ending at edge ``i`` spans lost events and is skipped. Returns (rpm, periods),
    ``(nan, 0)`` without a valid period."""
    t = np.asarray(t_us, dtype=np.int64)
    if t.size < 2:
        return float("nan"), 0
    dt = np.diff(t)
    ok = dt > 0
    if gap is not None:
        ok &= ~np.asarray(gap, dtype=bool)[1:]
    n = int(np.count_nonzero(ok))
    if n == 0:
        return float("nan"), 0
    return 60e6 * n / float(dt[ok].sum()), n


def current_rpm(last_edges_us, device_now_us: int, *, stale_factor: float = 3.0,
                timeout_us: int = 500_000) -> float:
    """Latest speed from the last two edges, or 0 if the channel went quiet."""
    if len(last_edges_us) < 2:
        return 0.0
    t1, t2 = int(last_edges_us[-2]), int(last_edges_us[-1])
    period = t2 - t1
    if period <= 0:
        return 0.0
    quiet = device_now_us - t2
    if quiet > min(timeout_us, stale_factor * period) and quiet > period:
        return 0.0
    return 60e6 / period
