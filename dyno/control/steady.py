"""Steady-state detection from the data (pure).

After a brake step the CVT shifts and the engine speed recovers over a few
seconds.  A window is *settled* when, over its last ``window_s`` split into
``blocks`` equal blocks, the block means of engine speed, secondary speed
and torque counts agree within tolerance and show no trend.  Block means
(not samples) are compared because a single-cylinder engine's firing ripple
makes individual samples scatter far more than the mean moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dyno.acquisition.rpm import rpm_by_count
from dyno.protocol import v1


@dataclass(frozen=True)
class SettleCriteria:
    window_s: float = 1.5
    blocks: int = 3
    rpm_rel_tol: float = 0.012  # block means within 1.2 % ...
    rpm_abs_tol: float = 25.0  # ... or 25 rpm, whichever is larger
    torque_rel_tol: float = 0.04
    torque_abs_tol_nm: float = 0.6
    min_settle_s: float = 1.0  # never measure sooner after a step
    max_settle_s: float = 8.0  # then fall back: measure anyway, flagged
    fixed_settle_s: float = 4.0  # the thesis's fixed settle time (mode "fixed")


def block_spread(values: list[float]) -> float:
    a = np.asarray(values, dtype=float)
    return float(a.max() - a.min()) if a.size else float("inf")


def is_settled(streams, t_end_us: int, counts_per_nm: float, offset_counts: float,
               c: SettleCriteria = SettleCriteria()) -> tuple[bool, dict]:
    """Whether the window ending at ``t_end_us`` is steady; returns (ok, diagnostics)."""
    w_us = int(c.window_s * 1e6)
    edges_b = np.linspace(t_end_us - w_us, t_end_us, c.blocks + 1).astype(np.int64)
    diag = {}
    ok = True
    for name, ch in (("primary", v1.CH_PRIMARY), ("secondary", v1.CH_SECONDARY)):
        means = []
        for a, b in zip(edges_b[:-1], edges_b[1:]):
            rpm, n = rpm_by_count(streams.edge_window(ch, int(a), int(b)))
            means.append(rpm if n else np.nan)
        if any(np.isnan(means)):
            diag[name] = "too few edges"
            ok = False
            continue
        spread = block_spread(means)
        tol = max(c.rpm_rel_tol * float(np.mean(means)), c.rpm_abs_tol)
        diag[name] = round(spread, 1)
        ok &= spread <= tol
    means = []
    for a, b in zip(edges_b[:-1], edges_b[1:]):
        _, codes, status = streams.adc_window(int(a), int(b))
        codes = codes[(status & v1.ADC_STATUS_ERR) == 0]
        means.append(codes.mean() if codes.size else np.nan)
    if any(np.isnan(means)):
        diag["torque"] = "too few conversions"
        return False, diag
    torque = (np.asarray(means) - offset_counts) / counts_per_nm
    spread = block_spread(torque)
    tol = max(c.torque_rel_tol * abs(float(torque.mean())), c.torque_abs_tol_nm)
    diag["torque"] = round(spread, 3)
    ok &= spread <= tol
    return bool(ok), diag
