"""When a measurement window may stop: the uncertainty's own uncertainty (pure).

A point is averaged *until* its standard error (or 95 % half-width) reaches a
target.  That error comes from batch means (:mod:`dyno.analysis.points`), and
with few batches it is itself uncertain: ``(B - 1) s_B^2 / sigma^2`` follows a
chi-squared law with ``B - 1`` degrees of freedom, so 6 batches underestimate
the true standard error by 2x about one time in 40.  Checked once a second,
a window whose true error is well above the target still stops, sooner or
later, on such a lucky estimate: the points that stop early are exactly the
ones whose error is understated (optional stopping).

The stopping rule therefore compares the one-sided upper confidence bound of
the standard error with the target, not the estimate itself:

.. math:: \\sigma \\le s_B \\sqrt{\\frac{B-1}{\\chi^2_{q}(B-1)}} \\quad\\text{with probability } 1-q,

which needs a much smaller estimate from 6 batches (x1.37 at ``q = 0.25``)
than from 48 (x1.08).  The *reported* standard error and interval stay the
plain estimates: only the decision to stop uses the bound.
"""

from __future__ import annotations

import math
from functools import lru_cache

#: One-sided level of the bound: a window whose true error equals the target stops at a given check
#: with this probability (25 %); one whose true error is 3x the target, at 6 batches, ~0.2 %.
STOP_QUANTILE = 0.25


@lru_cache(maxsize=256)
def sem_bound_factor(n_batches: int, quantile: float = STOP_QUANTILE) -> float:
    """``sqrt((B-1) / chi2_q(B-1))``: the factor from the batch-means standard error to its upper bound."""
    from scipy.stats import chi2

    dof = max(1, int(n_batches) - 1)
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"stop quantile must be in (0, 1), got {quantile!r}")
    return math.sqrt(dof / float(chi2.ppf(quantile, dof)))


def stop_uncertainty(point: dict, *, ci95: bool, quantile: float = STOP_QUANTILE) -> float:
    """The uncertainty a stopping rule compares with its target: the point's ``efficiency_ci95`` (or
    ``efficiency_sem``) times :func:`sem_bound_factor` of the window's batch count (NaN stays NaN)."""
    from dyno.analysis.points import batch_count

    u = point["efficiency_ci95"] if ci95 else point["efficiency_sem"]
    dof = point.get("efficiency_dof")  # (the estimate's own degrees of freedom: dyno.analysis.spectral_sem)
    n = int(dof) + 1 if dof else batch_count(point["t_start_us"], point["t_end_us"])
    return float(u) * sem_bound_factor(n, quantile)
