"""Two trips ahead: the probability that a tune meets the targets now *or after one adjustment*.

A team's second trip differs from its first: the run on the advised tune measures the parts it brought,
so the next change can be an *adjustment* whose effect is then known -- tuning washers added to or
taken off the same flyweight bodies, the same secondary spring clocked to another position (the same
physical parts, :func:`dyno.tuning.parts.part_identity`) -- where a new spring or body brings its whole
tolerance (±10 %: 60-75 rpm of engagement).  So "a stiff spring aimed high, trimmed with washers" can
beat "the spring whose label is closest": it fails the first trip more often, the second almost never.

For a candidate tune ``c`` with predicted figures ``y ~ N(mu, Sigma)`` (the calibration's covariance for
the parts the runs saw, the priors for the parts ``c`` brings, the model floor):

.. math:: P_2(c) = E_y\\big[\\max\\big(1_{hit}(y),\\ \\max_a \\textstyle\\prod_f
          P(|y_f + \\Delta_{a,f} - t_f| \\le tol \\mid u_{after,f})\\big)\\big]

``a`` ranges over the adjustments of ``c`` (washers on its flyweight bodies, positions of its secondary
spring, or both), ``Delta_a`` the change each makes to the figures (the forward model at the calibrated
values: linear in the draw, which is what one run's calibration then pins), and ``u_after`` the model
floor with a calibration residual :data:`U_AFTER_RPM`.  The expectation is a Monte Carlo over
:data:`N_DRAWS` Gaussian draws (a fixed seed: the ranking is reproducible).  The full-load figure is left
out (a root solve per adjustment): with a full-load target the ranking stays one trip deep.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erf

from dyno.tuning.advisor_model import (MODEL_SD_RPM, THRUST_NOMINAL, effective_tune, predict_figure, thrust_of,
                                       thrust_params, tune_params)
from dyno.tuning.parts import apply_part, part_identity

N_DRAWS = 2000
#: below the rig's "the secondary must turn" speed (SafetyLimits.secondary_check_primary_rpm, 2,600): a tune
#: that engages within this margin of it aborts the engagement plan's loaded ramps, so such an outcome teaches
#: nothing
ENGAGEMENT_MARGIN_RPM = 100.0


def engagement_limit_rpm() -> float:
    from dyno.control.safety import SafetyLimits

    return SafetyLimits().secondary_check_primary_rpm - ENGAGEMENT_MARGIN_RPM
#: what a figure's prediction keeps after the run that calibrated every part it uses (rpm, k = 1)
U_AFTER_RPM = 12.0
ADJUSTABLE = ("flyweights", "secondary_spring")


def adjustments(tune, catalogue) -> list:
    """Tunes reached from ``tune`` by re-setting its own parts (same physical part, another setting):
    washers on its flyweight bodies, positions of its secondary spring; one or both."""
    per_kind = []
    for kind in ADJUSTABLE:
        if getattr(tune, kind, None) is None:
            continue
        ident, here = part_identity(tune, kind), part_identity(tune, kind, with_settings=True)
        opts = [p for p in catalogue if p.kind == kind
                and part_identity(apply_part(tune, p), kind) == ident
                and part_identity(apply_part(tune, p), kind, with_settings=True) != here]
        per_kind.append(opts)
    out = [apply_part(tune, p) for opts in per_kind for p in opts]
    if len(per_kind) == 2:
        out.extend(apply_part(apply_part(tune, a), b) for a in per_kind[0] for b in per_kind[1])
    return out


def _figures(cal, tune, figures, load_nm, low_ratio, tol_of):
    """The light figures of ``tune`` at the calibrated values."""
    ps = tune_params(tune, tol_of)
    idx = cal.index()
    d = np.array([cal.d[idx[(p.part, p.field)]] if (p.part, p.field) in idx else 0.0 for p in ps])
    tp = thrust_params()
    thrust = thrust_of([cal.d[idx[(p.part, p.field)]] if (p.part, p.field) in idx else 0.0 for p in tp])
    eff = effective_tune(tune, ps, d)
    return np.array([predict_figure(eff, f, load_nm, low_ratio, None, None, thrust) for f in figures])


def figure_covariance(cal, tune, figures, load_nm, low_ratio, tol_of, step: float = 1e-3):
    """(mean, covariance) of the light ``figures`` of ``tune``: the gradients in every part deviation and
    the thrust ratio's parameters, the calibration's covariance where the runs saw them, the prior where
    not, the model floor on the diagonal."""
    ps = tune_params(tune, tol_of) + thrust_params()
    n_part = len(ps) - len(thrust_params())
    idx = cal.index()
    d0 = np.array([cal.d[idx[(p.part, p.field)]] if (p.part, p.field) in idx else 0.0 for p in ps])

    def f(x):
        eff = effective_tune(tune, ps[:n_part], x[:n_part])
        th = tuple(t + v for t, v in zip(THRUST_NOMINAL, x[n_part:]))
        return np.array([predict_figure(eff, fig, load_nm, low_ratio, None, None, th) for fig in figures])

    y0 = f(d0)
    g = np.zeros((len(figures), len(ps)))
    for i in range(len(ps)):
        dp, dm = d0.copy(), d0.copy()
        dp[i] += step
        dm[i] -= step
        g[:, i] = (f(dp) - f(dm)) / (2 * step)
    cov_d = np.zeros((len(ps), len(ps)))
    seen = [i for i, p in enumerate(ps) if (p.part, p.field) in idx]
    if seen:
        ci = [idx[(ps[i].part, ps[i].field)] for i in seen]
        cov_d[np.ix_(seen, seen)] = cal.cov[np.ix_(ci, ci)]
    for i, p in enumerate(ps):
        if (p.part, p.field) not in idx:
            cov_d[i, i] = p.prior_sd ** 2
    cov = g @ cov_d @ g.T + np.diag([MODEL_SD_RPM[fig] ** 2 for fig in figures])
    return y0, cov


def two_trip_probability(cal, tune, catalogue, targets: dict, tolerance_rpm: float, load_nm: float,
                         low_ratio: float, tol_of, mean=None, cov=None) -> float:
    """:math:`P_2` of ``tune`` (module docstring) for the light figures of ``targets``."""
    figures = [f for f in targets if f != "full_load"]
    if mean is None or cov is None:
        mean, cov = figure_covariance(cal, tune, figures, load_nm, low_ratio, tol_of)
    if not np.all(np.isfinite(mean)) or not np.all(np.isfinite(cov)):
        return 0.0
    t = np.array([targets[f] for f in figures])
    w, v = np.linalg.eigh(cov)
    root = v * np.sqrt(np.clip(w, 0.0, None))
    rng = np.random.default_rng(20251127)
    y = mean + rng.standard_normal((N_DRAWS, len(figures))) @ root.T          # draws x figures
    best = np.all(np.abs(y - t) <= tolerance_rpm, axis=1).astype(float)
    # a draw that engages too high for the rig aborts: no figure, nothing calibrated, no second chance
    runs = np.ones(N_DRAWS, dtype=bool)
    if "engagement" in figures:
        runs = y[:, figures.index("engagement")] <= engagement_limit_rpm()
        best = best * runs
    adj = adjustments(tune, catalogue)
    if adj:
        here = _figures(cal, tune, figures, load_nm, low_ratio, tol_of)
        delta = np.array([_figures(cal, a, figures, load_nm, low_ratio, tol_of) for a in adj]) - here
        delta = delta[np.all(np.isfinite(delta), axis=1)]
        if delta.size:
            u = np.array([math.hypot(MODEL_SD_RPM[f], U_AFTER_RPM) for f in figures]) * math.sqrt(2.0)
            ya = y[:, None, :] + delta[None, :, :]                              # draws x adj x figures
            p = 0.5 * (erf((t + tolerance_rpm - ya) / u) - erf((t - tolerance_rpm - ya) / u))
            best = np.maximum(best, np.prod(p, axis=2).max(axis=1) * runs)
    return float(best.mean())
