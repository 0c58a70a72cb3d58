r"""The standard error of a window's mean from the low-frequency end of its spectrum (pure).

Why not batch means alone
-------------------------
A mean's standard error is set by the samples' spectral density at zero frequency,
:math:`\operatorname{Var}(\bar x) \approx S(0)/n` (per-sample units).  Batch means estimate
:math:`S(0)` with only ``B - 1`` degrees of freedom (6 batches of 0.5 s in a 3 s window: 5), so the
95 % half-width carries Student's :math:`t_{0.975}(5) = 2.57` instead of 1.96 and a stopping rule
that judges the error's upper bound (:mod:`dyno.analysis.stopping`) another x1.37: a window must be
~3x longer than the noise needs.  The torque channel's noise is white at the converter (the
conversions' own noise, :mod:`dyno.sim.rig_signals`) plus narrow lines at the firing, revolution and
brake-shaft orders (>= ~10 Hz at test speeds).  So the periodogram's first ``K`` bins below a cut-off
well under those lines each estimate :math:`S(0)` with 2 degrees of freedom (Heidelberger & Welch
1981, "A spectral method for confidence interval generation and run length control in simulations"):

.. math:: \hat S(0) = \frac1K \sum_{k=1}^{K} I_k,\qquad I_k = \frac{|X_k|^2}{n},\qquad
          X_k = \sum_j (x_j - \bar x)\, e^{-2\pi i jk/n},\qquad k/T \le f_{cut},

:math:`\hat S(0)/n` is the variance of the mean with :math:`2K` degrees of freedom (a 3 s window at a
4 Hz cut-off: 24).  A slow drift in the window (a speed still settling, the rotor's fade) puts power in
those bins: the estimate grows (conservative), it does not hide it.  The lines' leakage into the bins
falls as the bin distance squared (rectangular window, >= 6 Hz away: < 10 % of the white floor at the
largest measured ripple).
"""

from __future__ import annotations

import math

import numpy as np

#: Below the lowest ripple line at test speeds (the brake shaft's order: n_s g / 60 >= 10 Hz at 1,150 rpm).
F_CUT_HZ = 4.0
#: Fewer bins than this: the estimate is too uncertain to use (the caller falls back to batch means).
MIN_BINS = 4


def spectral_sem(values, duration_s: float, f_cut_hz: float = F_CUT_HZ) -> tuple[float, int]:
    """(standard error of the mean, degrees of freedom) of evenly spaced ``values`` spanning ``duration_s``;
    (NaN, 0) when the window holds fewer than :data:`MIN_BINS` bins below ``f_cut_hz``."""
    x = np.asarray(values, dtype=float)
    n = x.size
    if n < 4 or not duration_s > 0:
        return math.nan, 0
    k_max = min(int(math.floor(f_cut_hz * duration_s)), (n - 1) // 2)
    if k_max < MIN_BINS:
        return math.nan, 0
    spec = np.fft.rfft(x - x.mean())
    s0 = float(np.mean(np.abs(spec[1:k_max + 1]) ** 2) / n)
    return math.sqrt(s0 / n), 2 * k_max


def satterthwaite_dof(parts: list[tuple[float, float]]) -> float:
    r"""Welch-Satterthwaite: the degrees of freedom of a sum of variances ``[(variance, dof), ...]``,
    :math:`(\sum v_i)^2 / \sum (v_i^2/\nu_i)` (terms with no variance ignored)."""
    num = sum(v for v, _ in parts if v > 0)
    den = sum(v * v / d for v, d in parts if v > 0 and d > 0)
    return num * num / den if den > 0 else math.nan
