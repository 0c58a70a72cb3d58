"""Torque-sensor calibration: the known loads, the fit, its reproducibility over repeats.

The rig measures torque with a strain-gauge bridge on the brake-rotor shaft,
downstream of a 32:61 gear reduction, digitised by a 16-bit ADC (Messick 2018,
Sections 8.2.2 and 9.2); the engine-side input channel (issue 27) with a load
cell on the engine cradle's arm.  The calibration maps ADC counts to torque
(thesis eq 9.1)::

    counts = slope_counts_per_nm * T_nm + intercept_counts
    ADC    = 108.19 T + 35145                                      (eq 9.1)

Known loads are applied by hanging a mass from a rope wrapped on the brake
rotor with the secondary locked (or on the cradle's arm); see
:func:`torque_from_mass`.

The history entry and the history file (parsing, validation, atomic append)
are in :mod:`dyno.analysis.calibration_history`.  This module does no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dyno.analysis.calibration_history import (G_STANDARD_M_PER_S2, GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY,
                                               R2_MIN_DEFAULT, CalibrationEntry, CalibrationRejected)

__all__ = ["torque_from_mass", "CalibrationFit", "fit_calibration",
           "REPRODUCIBILITY_TARGET_REL", "Reproducibility", "slope_reproducibility", "fit_repeats", "check_loads"]

# --------------------------------------------------------------------------
# applying known loads and fitting the line


def torque_from_mass(mass_kg, lever_arm_m, gear_ratio_brake_per_secondary=GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY,
                     g=G_STANDARD_M_PER_S2):
    """Secondary-shaft torque from a mass hung on a rope round the brake rotor.

    .. math::

        T_{brake} = m g r, \\qquad T_s = T_{brake} \\, \\frac{\\omega_{brake}}{\\omega_s}
                  = m g r \\cdot \\tfrac{32}{61}

    The rope tension ``m g`` acts at the rope radius ``r`` (rotor radius plus
    half the rope diameter).  The reduction is taken as lossless (static
    test, thesis Section 8.1), so power balance gives the secondary torque as
    the brake-shaft torque times the speed ratio.

    Parameters
    ----------
    mass_kg : float or array_like
        Hanging mass including the bucket, kg (>= 0).
    lever_arm_m : float
        Rope radius on the brake rotor, m (> 0).
    gear_ratio_brake_per_secondary : float
        Brake rpm per secondary rpm (32/61 on the thesis rig).
    g : float
        Local gravitational acceleration, m/s^2.

    Returns
    -------
    float or numpy.ndarray
        Torque on the CVT secondary, N·m.
    """
    m = np.asarray(mass_kg, dtype=float)
    for name, v in (("lever_arm_m", lever_arm_m), ("gear_ratio_brake_per_secondary",
                                                   gear_ratio_brake_per_secondary), ("g", g)):
        if not (math.isfinite(float(v)) and float(v) > 0):
            raise ValueError(f"torque_from_mass: {name} must be a finite number > 0, got {v!r}")
    if not np.all(np.isfinite(m)) or np.any(m < 0):
        raise ValueError("torque_from_mass: mass_kg must be finite and >= 0")
    t = m * g * lever_arm_m * gear_ratio_brake_per_secondary
    return float(t) if t.ndim == 0 else t


@dataclass(frozen=True, eq=False)
class CalibrationFit:
    """Result of :func:`fit_calibration` (all counts are raw ADC counts).

    Attributes
    ----------
    slope_counts_per_nm, intercept_counts : float
        Least-squares line ``counts = slope * T + intercept``.
    slope_se_counts_per_nm, intercept_se_counts : float
        Standard errors from the step-to-step scatter (n_steps - 2 dof).
    cov_slope_intercept : float
        Covariance of slope and intercept (needed to propagate into torque).
    r2 : float
        Coefficient of determination of the step means.
    torques_nm, counts_mean, residuals_counts, n_samples_per_step : numpy.ndarray
        Per step: applied secondary torque, mean counts, residual, samples.
    n_samples : int
        Total ADC samples (number of steps if only means were given).
    n_distinct_loads : int
    full_scale_counts : float
        Output span used for the percentages.
    nonlinearity_pct_fs : float
        ``max |residual| / full_scale_counts * 100``.
    hysteresis_counts, hysteresis_pct_fs : float or None
        Largest loading-vs-unloading difference at a common load; None if no
        direction was given or no load was visited in both directions.
    within_step_sd_counts : float or None
        Pooled within-step standard deviation (raw input only): the ripple.
    friction_counts : float or None
        With ``friction_term``: the fitted offset of the loading branch from the line (the unloading
        branch's is its negative), counts; None otherwise.  A cradle's bearings hold ``b`` of the load
        off the cell while it is loaded and add it while it is unloaded: ``-friction_counts / slope``
        is ``b`` (N·m), half the hysteresis.
    """

    slope_counts_per_nm: float
    intercept_counts: float
    slope_se_counts_per_nm: float
    intercept_se_counts: float
    cov_slope_intercept: float
    r2: float
    torques_nm: np.ndarray
    counts_mean: np.ndarray
    residuals_counts: np.ndarray
    n_samples_per_step: np.ndarray
    n_samples: int
    n_distinct_loads: int
    full_scale_counts: float
    nonlinearity_pct_fs: float
    hysteresis_counts: float | None = None
    hysteresis_pct_fs: float | None = None
    within_step_sd_counts: float | None = None
    friction_counts: float | None = None
    friction_se_counts: float | None = None

    @property
    def friction_nm(self) -> float | None:
        """The friction torque the loading/unloading offset stands for (N·m; None without the term)."""
        return None if self.friction_counts is None else -self.friction_counts / self.slope_counts_per_nm

    def to_entry(self, date: str, *, lever_arm_m: float | None = None,
                 gear_ratio_brake_per_secondary: float = GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY,
                 note: str = "") -> CalibrationEntry:
        """A history entry for this fit (append it with :func:`append_entry`)."""
        return CalibrationEntry(date=date, slope_counts_per_nm=self.slope_counts_per_nm,
                                intercept_counts=self.intercept_counts, r2=self.r2,
                                n_samples=self.n_samples, lever_arm_m=lever_arm_m,
                                gear_ratio_brake_per_secondary=gear_ratio_brake_per_secondary,
                                note=note)


def _distinct_groups(values: np.ndarray) -> np.ndarray:
    """Group label per value; loads equal to 1e-9 relative are the same load."""
    order = np.argsort(values, kind="stable")
    labels = np.empty(len(values), dtype=int)
    label = -1
    prev = None
    for i in order:
        v = values[i]
        if prev is None or not math.isclose(v, prev, rel_tol=1e-9, abs_tol=1e-12):
            label += 1
            prev = v
        labels[i] = label
    return labels


def _direction_sign(d) -> int:
    if isinstance(d, str):
        key = d.strip().lower()
        if key in ("up", "load", "loading", "+", "+1"):
            return 1
        if key in ("down", "unload", "unloading", "-", "-1"):
            return -1
    elif d in (1, -1) and not isinstance(d, bool):
        return int(d)
    raise ValueError(f"fit_calibration: direction must be +1/'up' (loading) or -1/'down' "
                     f"(unloading), got {d!r}")


def fit_calibration(torques_nm, counts, *, n_samples=None, direction=None,
                    r2_min: float = R2_MIN_DEFAULT, full_scale_nm: float | None = None,
                    min_distinct_loads: int = 3, friction_term: bool = False) -> CalibrationFit:
    """Fit ``counts = slope * T + intercept`` to a calibration run.

    Parameters
    ----------
    torques_nm : array_like, shape (n_steps,)
        Applied secondary torque per step, N·m (see :func:`torque_from_mass`).
    counts : array_like
        Either per-step mean counts, shape (n_steps,), or raw samples per
        step: a 2-D array (n_steps, n) or a sequence of 1-D arrays (ragged).
    n_samples : array_like of int, optional
        Samples behind each per-step mean (only with means; recorded, not used
        as weights).  Default 1 per step.
    direction : sequence, optional
        Per step +1/'up' while loading, -1/'down' while unloading, to compute
        hysteresis.
    r2_min : float
        Refuse the fit below this R^2 (default 0.999).
    full_scale_nm : float, optional
        Torque span defining full scale for the percentages; default the
        calibrated span ``max(T) - min(T)``.
    min_distinct_loads : int
        Refuse with fewer distinct loads (default 3: two points always lie on
        a line, so they cannot show non-linearity or a bad point).
    friction_term : bool
        Fit ``counts = slope * T + intercept + f * s`` with ``s`` = +1 loading,
        -1 unloading (needs ``direction`` with both; ignored otherwise): the
        line between the two branches of a sensor with Coulomb friction in
        its load path (the engine cradle's bearings).  Without it a sequence
        that visits its top load only while loading tilts the line by about
        ``-0.036 b`` per N·m of friction ``b`` (2…10 kg on 0.2 m: -0.25 % at
        the simulated cradle's typical 0.07 N·m).

    Returns
    -------
    CalibrationFit

    Raises
    ------
    CalibrationRejected
        Too few distinct loads, R^2 below ``r2_min``, or a non-positive slope.
    ValueError
        Malformed input (lengths, non-finite values).

    Notes
    -----
    Ordinary least squares on the *step means*, one point per load step:

    .. math::

        a = \\frac{\\sum (T_i - \\bar T)(c_i - \\bar c)}{\\sum (T_i - \\bar T)^2},
        \\quad b = \\bar c - a \\bar T, \\quad
        s^2 = \\frac{\\sum r_i^2}{n - 2},

        \\mathrm{se}(a) = \\frac{s}{\\sqrt{S_{TT}}}, \\quad
        \\mathrm{se}(b) = s \\sqrt{\\frac{1}{n} + \\frac{\\bar T^2}{S_{TT}}}, \\quad
        \\mathrm{cov}(a, b) = -\\bar T s^2 / S_{TT}.

    Raw samples are reduced to step means first, on purpose: the hundreds of
    samples in one step are correlated (bridge drift, mechanical ripple), so
    fitting them as independent points would shrink the standard errors by
    about :math:`\\sqrt{n}` without making the line any better known.  The
    step-to-step scatter is the honest error of the line.

    Non-linearity is :math:`\\max_i |r_i| / FS \\times 100` with
    :math:`FS = a \\cdot` ``full_scale_nm``.  Hysteresis is
    :math:`\\max_T |\\bar c_{up}(T) - \\bar c_{down}(T)|` over loads visited
    both loading and unloading.
    """
    t = np.asarray(torques_nm, dtype=float)
    if t.ndim != 1 or len(t) == 0:
        raise ValueError("fit_calibration: torques_nm must be a non-empty 1-D array")
    n_steps = len(t)

    within_sd = None
    if isinstance(counts, np.ndarray) and counts.ndim == 2 or (
            not isinstance(counts, np.ndarray) and len(counts) > 0
            and all(np.ndim(c) == 1 for c in counts)):
        # Raw samples per step.
        if n_samples is not None:
            raise ValueError("fit_calibration: n_samples is implied by raw samples; do not pass it")
        steps = [np.asarray(c, dtype=float) for c in counts]
        if len(steps) != n_steps:
            raise ValueError(f"fit_calibration: {n_steps} torques but {len(steps)} sample arrays")
        for i, s in enumerate(steps):
            if len(s) == 0 or not np.all(np.isfinite(s)):
                raise ValueError(f"fit_calibration: step {i} samples must be non-empty and finite")
        c_mean = np.array([s.mean() for s in steps])
        n_per = np.array([len(s) for s in steps], dtype=int)
        dof = int(np.sum(n_per - 1))
        if dof > 0:
            within_sd = float(np.sqrt(sum(np.sum((s - s.mean()) ** 2) for s in steps) / dof))
    else:
        c_mean = np.asarray(counts, dtype=float)
        if c_mean.shape != (n_steps,):
            raise ValueError(f"fit_calibration: {n_steps} torques but counts shape {c_mean.shape}")
        if n_samples is None:
            n_per = np.ones(n_steps, dtype=int)
        else:
            n_per = np.asarray(n_samples)
            if n_per.shape != (n_steps,) or not np.all(n_per == np.round(n_per)) or np.any(n_per < 1):
                raise ValueError("fit_calibration: n_samples must be one integer >= 1 per step")
            n_per = n_per.astype(int)
    if not np.all(np.isfinite(t)) or not np.all(np.isfinite(c_mean)):
        raise ValueError("fit_calibration: torques and counts must be finite")

    groups = _distinct_groups(t)
    n_distinct = int(groups.max()) + 1
    if n_distinct < min_distinct_loads:
        raise CalibrationRejected(
            f"only {n_distinct} distinct load(s); at least {min_distinct_loads} are needed to "
            f"check linearity (add more masses)")

    sign = None
    if direction is not None:
        if len(direction) != n_steps:
            raise ValueError(f"fit_calibration: {n_steps} torques but {len(direction)} directions")
        sign = np.array([_direction_sign(d) for d in direction])
    t_bar = t.mean()
    c_bar = c_mean.mean()
    s_tt = float(np.sum((t - t_bar) ** 2))
    friction = friction_se = None
    if friction_term and sign is not None and np.any(sign > 0) and np.any(sign < 0) and n_steps > 3:
        # least squares on [T, 1, s]; standard errors from (X'X)^-1 with n - 3 dof
        x = np.column_stack([t, np.ones(n_steps), sign.astype(float)])
        beta, *_ = np.linalg.lstsq(x, c_mean, rcond=None)
        slope, intercept, friction = (float(v) for v in beta)
        resid = c_mean - x @ beta
        ss_res = float(np.sum(resid ** 2))
        cov = ss_res / (n_steps - 3) * np.linalg.inv(x.T @ x)
        slope_se, intercept_se, friction_se = (math.sqrt(cov[i, i]) for i in range(3))
        cov_ab = float(cov[0, 1])
    else:
        slope = float(np.sum((t - t_bar) * (c_mean - c_bar)) / s_tt)
        intercept = float(c_bar - slope * t_bar)
        resid = c_mean - (slope * t + intercept)
        ss_res = float(np.sum(resid ** 2))
        s2 = ss_res / (n_steps - 2)
        slope_se = math.sqrt(s2 / s_tt)
        intercept_se = math.sqrt(s2 * (1.0 / n_steps + t_bar ** 2 / s_tt))
        cov_ab = -t_bar * s2 / s_tt
    ss_tot = float(np.sum((c_mean - c_bar) ** 2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else 0.0
    r2 = min(max(r2, 0.0), 1.0)  # guard rounding just outside [0, 1]

    if not slope > 0:
        raise CalibrationRejected(
            f"slope {slope:.6g} counts/N·m is not positive: bridge or amplifier wired with the "
            f"opposite sign, or loads applied in the wrong direction")
    if r2 < r2_min:
        raise CalibrationRejected(
            f"R^2 = {r2:.6f} is below the required {r2_min} (largest residual "
            f"{np.max(np.abs(resid)):.1f} counts at {t[np.argmax(np.abs(resid))]:.3g} N·m): "
            f"check for a slipping rope, a rubbing brake or a load that was still swinging")

    span_nm = float(full_scale_nm) if full_scale_nm is not None else float(t.max() - t.min())
    if not (math.isfinite(span_nm) and span_nm > 0):
        raise ValueError(f"fit_calibration: full_scale_nm must be > 0, got {full_scale_nm!r}")
    fs_counts = slope * span_nm
    nonlin = float(np.max(np.abs(resid)) / fs_counts * 100.0)

    hyst = hyst_pct = None
    if sign is not None:
        diffs = []
        for g in range(n_distinct):
            up = c_mean[(groups == g) & (sign > 0)]
            down = c_mean[(groups == g) & (sign < 0)]
            if len(up) and len(down):
                diffs.append(abs(up.mean() - down.mean()))
        if diffs:
            hyst = float(max(diffs))
            hyst_pct = hyst / fs_counts * 100.0

    return CalibrationFit(
        slope_counts_per_nm=slope, intercept_counts=intercept,
        slope_se_counts_per_nm=slope_se, intercept_se_counts=intercept_se,
        cov_slope_intercept=cov_ab, r2=r2, torques_nm=t, counts_mean=c_mean,
        residuals_counts=resid, n_samples_per_step=n_per, n_samples=int(n_per.sum()),
        n_distinct_loads=n_distinct, full_scale_counts=fs_counts, nonlinearity_pct_fs=nonlin,
        hysteresis_counts=hyst, hysteresis_pct_fs=hyst_pct, within_step_sd_counts=within_sd,
        friction_counts=friction, friction_se_counts=friction_se,
    )


# --------------------------------------------------------------------------
# the load plan


def check_loads(masses_kg, *, min_distinct: int = 3) -> list[str]:
    """Why a list of masses would not calibrate well ([] if it is fine).

    At least ``min_distinct`` distinct non-zero loads, and spread over the
    range: the lightest at most 40 % of the heaviest, and no gap between
    neighbouring loads wider than 60 % of the span (a line through two
    clusters cannot show non-linearity in between).
    """
    problems = []
    m = sorted({round(float(x), 9) for x in masses_kg})
    if any(not math.isfinite(x) or x <= 0 for x in m):
        problems.append("masses must be finite and > 0 kg")
        return problems
    if len(m) < min_distinct:
        problems.append(f"{len(m)} distinct load(s): at least {min_distinct} are needed to check linearity")
        return problems
    span = m[-1] - m[0]
    if m[0] > 0.4 * m[-1]:
        problems.append(f"lightest load {m[0]:g} kg is over 40 % of the heaviest ({m[-1]:g} kg): "
                        f"add a light load so the fit covers the low end")
    gaps = [b - a for a, b in zip(m, m[1:])]
    if span > 0 and max(gaps) > 0.6 * span:
        problems.append(f"a gap of {max(gaps):g} kg between loads (over 60 % of the range): add a load in between")
    return problems


# --------------------------------------------------------------------------
# repeats: the slope's reproducibility

#: The calibration reproducibility (relative standard deviation of the slope, each channel) that brings
#: the mean ``efficiency_u95`` of the map-free path to about 2 pp, on simulated rigs
#: (``bench/bench_input_torque.py --repro 0.004``; docs/analysis.md).
REPRODUCIBILITY_TARGET_REL = 0.004


@dataclass(frozen=True)
class Reproducibility:
    """The slope's scatter over repeated calibrations (the same loads applied again, loading and unloading).

    ``rel_sd`` is one calibration's reproducibility, ``sd(a_k) / mean(a_k)`` (n - 1 dof), the figure a
    history's slope spread estimates and the efficiency's calibration term uses
    (:func:`dyno.analysis.systematic.calibration_rel_u`); ``rel_se = rel_sd / sqrt(n)`` is the mean slope's.
    NaN with fewer than two repeats (one calibration cannot show its own reproducibility).
    """

    slopes: tuple
    mean_slope: float
    rel_sd: float
    rel_se: float

    @property
    def n(self) -> int:
        return len(self.slopes)

    def meets(self, target_rel: float = REPRODUCIBILITY_TARGET_REL) -> bool:
        return math.isfinite(self.rel_sd) and self.rel_sd <= target_rel


def slope_reproducibility(slopes) -> Reproducibility:
    """:class:`Reproducibility` of the slopes of repeated calibrations (each > 0)."""
    a = [float(x) for x in slopes]
    if not a or not all(math.isfinite(x) and x > 0 for x in a):
        raise ValueError("slope_reproducibility: one finite slope > 0 per repeat")
    mean = math.fsum(a) / len(a)
    if len(a) < 2:
        return Reproducibility(tuple(a), mean, math.nan, math.nan)
    sd = math.sqrt(math.fsum((x - mean) ** 2 for x in a) / (len(a) - 1))
    return Reproducibility(tuple(a), mean, sd / mean, sd / mean / math.sqrt(len(a)))


def fit_repeats(torques_nm, counts, repeat, *, direction=None, r2_min: float = R2_MIN_DEFAULT,
                min_distinct_loads: int = 3, friction_term: bool = False) -> tuple[CalibrationFit, Reproducibility]:
    """The line through every step of every repeat, and the slope's reproducibility across the repeats.

    ``repeat`` gives each step's repeat (any hashable; the order of first appearance is kept).  Each
    repeat is fitted on its own steps with the same checks as the whole (:func:`fit_calibration`; a
    refusal names the repeat), its slope one sample of the reproducibility; the returned fit is the one
    over all steps (its standard errors from the step-to-step scatter of them all).
    """
    t = list(torques_nm)
    if len(repeat) != len(t) or len(counts) != len(t) or (direction is not None and len(direction) != len(t)):
        raise ValueError("fit_repeats: one torque, one counts entry, one repeat (and direction) per step")
    whole = fit_calibration(t, counts, direction=direction, r2_min=r2_min, min_distinct_loads=min_distinct_loads,
                            friction_term=friction_term)
    order = list(dict.fromkeys(repeat))
    slopes = []
    if len(order) > 1:
        for k, key in enumerate(order):
            idx = [i for i, r in enumerate(repeat) if r == key]
            try:
                f = fit_calibration([t[i] for i in idx], [counts[i] for i in idx],
                                    direction=None if direction is None else [direction[i] for i in idx],
                                    r2_min=r2_min, min_distinct_loads=min_distinct_loads,
                                    friction_term=friction_term)
            except CalibrationRejected as exc:
                raise CalibrationRejected(f"repeat {k + 1} of {len(order)}: {exc}") from None
            slopes.append(f.slope_counts_per_nm)
    else:
        slopes.append(whole.slope_counts_per_nm)
    return whole, slope_reproducibility(slopes)
