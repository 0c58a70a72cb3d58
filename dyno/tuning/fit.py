"""Fit the shift model's uncertain parameters to logged runs (issue 7, part E).

Three parameters are not on any drawing and are estimated from the rig:

* ``belt_friction_coefficient`` -- belt-sheave friction ``f`` of the
  closed-form belt thrusts (Sorge & Cammalleri eqs. 17-18): it sets how much
  secondary clamp the belt requires for a primary clamp and torque;
* ``flyweight_radius_offset_m`` -- an offset of the flyweight radius table
  (Messick eq. 9.2 with ``r(z) + dr`` at the same ``dr/dz``): the flyweights'
  real centre of mass;
* ``secondary_friction_torque_nm`` -- drag on the secondary shaft after the
  helix: the helix (Sorge eq. 22) feels the measured output torque plus this.

Each measured steady point gives engine rpm ``n_e``, secondary rpm ``n_s``
and secondary (output) torque ``T_out``.  The model predicts the engine rpm
at the measured secondary rpm and load: with the geometric ratio
``R = n_e eta_s / n_s`` (``eta_s`` the belt's elastic creep from the same
closed form), the primary torque from the run's engine map (the steady-state
test runs at full throttle), the primary clamp from the tune, and the helix
torque ``T_out + T_fr``, the secondary actuator force must equal the belt's
requirement.  Using the measured load (not the model's torque efficiency)
keeps the unmodelled belt torque loss out of the fit.

The least-squares residual of a point is the Newton step
``g(n_e) / g'(n_e)`` of the force residual ``g`` (secondary actuator minus
belt requirement) along ``n_s = const``: to first order the measured minus
predicted engine rpm, for 3 closed-form calls instead of a root solve.
Reported residuals (before and after) use the exact prediction
(:func:`predict_engine_rpm`).  Uncertainties: ``cov = s^2 (J^T J)^-1`` with
``s^2`` the residual variance per degree of freedom, so they include any
model error the residuals show, not only the sensor noise.

Points whose measured ratio sits on a ratio stop carry no information on the
parameters (the stop, not the force balance, sets the ratio); they are kept
out of the fit but in the reported residuals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.optimize import brentq, least_squares

from dyno.errors import MODEL_FAILURES, ConfigError
from dyno.model.closed_form import closed_form_point
from dyno.model.params import BeltParams, OperatingPoint
from dyno.tuning import actuators as act
from dyno.tuning.shift_curve import EngineMap, Solver, load_engine_map
from dyno.tuning.tune import model_params_for
from dyno.tuning.tune import Tune, load_tune

#: Fit parameters, in order, with the nominal value (the prior guess the fit
#: starts from: thesis belt friction, the tune's radius table, no drag) and
#: the scale the optimiser works in (a typical size of the correction).
PARAMETERS: tuple[str, ...] = ("belt_friction_coefficient", "flyweight_radius_offset_m",
                               "secondary_friction_torque_nm")
NOMINAL: tuple[float, ...] = (BeltParams().friction_coefficient, 0.0, 0.0)
SCALE: tuple[float, ...] = (0.05, 1e-3, 0.5)
UNITS: dict[str, str] = {"belt_friction_coefficient": "", "flyweight_radius_offset_m": "m",
                         "secondary_friction_torque_nm": "N m"}

#: A measured speed ratio within this fraction of a stop is "on the stop".
STOP_TOLERANCE_FRAC = 0.01
#: Engine-rpm step of the Newton residual's derivative (rpm).
DERIVATIVE_STEP_RPM = 2.0


@dataclass(frozen=True)
class MeasuredPoint:
    engine_rpm: float
    secondary_rpm: float
    secondary_torque_nm: float  # output torque at the gauge (after the shaft drag)


@dataclass
class FitRun:
    """One logged run: its tune, its engine map and its steady points."""

    name: str
    tune: Tune
    engine: EngineMap
    points: list[MeasuredPoint]


@dataclass
class FitResult:
    parameters: dict[str, float]
    sigma: dict[str, float]
    covariance: np.ndarray
    correlation: np.ndarray
    residual_std_rpm: float  # s: residual scatter per degree of freedom (fitted points)
    n_points_fit: int
    dof: int
    before: dict[str, Any]  # residual summaries with the nominal parameters
    after: dict[str, Any]   # ... and the fitted ones
    optimizer: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"parameters": self.parameters, "sigma": self.sigma,
                "correlation": self.correlation.tolist(), "residual_std_rpm": self.residual_std_rpm,
                "n_points_fit": self.n_points_fit, "dof": self.dof, "before": self.before, "after": self.after,
                "optimizer": self.optimizer}


# ------------------------------------------------------------------ loading


def load_fit_run(run_dir: str | Path, tune: Tune | str | Path | None = None,
                 engine: EngineMap | str | Path | None = None) -> FitRun:
    """A logged run for the fit.

    The tune is the run's ``tune.toml`` unless given (runs do not record
    their tune yet unless the test's setup hook saved it there); the engine
    map is the one stored with the run (``engine_map.csv``) unless given.
    """
    from dyno.runlog.reader import load_run

    run_dir = Path(run_dir)
    run = load_run(run_dir)
    if tune is None:
        tune_path = run_dir / "tune.toml"
        if not tune_path.exists():
            raise ConfigError(run_dir, "tune.toml", "the run's tune (or pass one with the run)")
        tune = load_tune(tune_path)
    elif not isinstance(tune, Tune):
        tune = load_tune(tune)
    if engine is None:
        engine = load_engine_map(run.engine_map_path or run_dir / "engine_map.csv")
    elif not isinstance(engine, EngineMap):
        engine = load_engine_map(engine)
    pts = []
    for p in run.points:
        n_e, n_s, t = (p.get(k, math.nan) for k in ("rpm_primary", "rpm_secondary", "torque_secondary_nm"))
        if p.get("valid", True) and all(v is not None and math.isfinite(v) for v in (n_e, n_s, t)) and n_s > 0:
            pts.append(MeasuredPoint(float(n_e), float(n_s), float(t)))
    return FitRun(run_dir.name, tune, engine, pts)


# ------------------------------------------------------------------ model


def solver_for(tune: Tune, engine: EngineMap, parameters: Sequence[float]) -> Solver:
    """The shift-curve solver with the fit parameters ``(f, dr, T_fr)``."""
    f, dr, t_fr = (float(v) for v in parameters)
    params = model_params_for(tune, replace(BeltParams(), friction_coefficient=f))
    return Solver(tune, engine, params, secondary_friction_torque_nm=t_fr, flyweight_radius_offset_m=dr)


def _force_residual_n(solver: Solver, engine_rpm: float, secondary_rpm: float, secondary_torque_nm: float,
                      creep_eta: float) -> tuple[float, float]:
    """(secondary actuator - belt requirement, belt speed efficiency) at the
    ratio the speeds give; +1e6 N where the primary clamp cannot hold the
    belt (the secondary wins, as in :meth:`Solver.residual_n`)."""
    ratio = engine_rpm * creep_eta / secondary_rpm
    r_p = solver.primary_radius_for_ratio(ratio)
    m_e = float(solver.engine.torque_at_nm(engine_rpm))
    f_p = solver.primary_force_n(engine_rpm, r_p)
    if m_e <= 0 or f_p <= 0:
        return 1e6, creep_eta
    op = OperatingPoint(ratio=ratio, primary_speed_rpm=engine_rpm, primary_torque_nm=m_e,
                        slack_tension_n=None, primary_axial_force_n=f_p)
    try:
        res = closed_form_point(solver.params, op)
    except (ConfigError, *MODEL_FAILURES):
        return 1e6, creep_eta
    helix_torque_nm = secondary_torque_nm + solver.secondary_friction_torque_nm
    f_s_act = float(act.secondary_axial_force_n(solver.tune, helix_torque_nm, res.r_secondary_m,
                                                closing=solver.closing))
    return f_s_act - res.axial_force_secondary_n, res.efficiency_speed


def _creep_eta(solver: Solver, point: MeasuredPoint) -> float:
    _, eta = _force_residual_n(solver, point.engine_rpm, point.secondary_rpm, point.secondary_torque_nm, 1.0)
    return eta


def on_stop(solver: Solver, point: MeasuredPoint, tolerance_frac: float = STOP_TOLERANCE_FRAC) -> str | None:
    """"high_stop" / "low_stop" if the measured ratio sits on a stop, else None."""
    ratio = point.engine_rpm / point.secondary_rpm
    if ratio <= solver.ratio_high_stop * (1.0 + tolerance_frac):
        return "high_stop"
    if ratio >= solver.ratio_low_stop * (1.0 - tolerance_frac):
        return "low_stop"
    return None


def newton_residual_rpm(solver: Solver, point: MeasuredPoint, creep_eta: float | None = None) -> float:
    """Measured minus predicted engine rpm to first order: ``g / g'`` at the
    measured engine rpm along constant secondary rpm and load."""
    eta = _creep_eta(solver, point) if creep_eta is None else creep_eta
    h = DERIVATIVE_STEP_RPM
    g0, _ = _force_residual_n(solver, point.engine_rpm, point.secondary_rpm, point.secondary_torque_nm, eta)
    g1, _ = _force_residual_n(solver, point.engine_rpm + h, point.secondary_rpm, point.secondary_torque_nm, eta)
    slope = (g1 - g0) / h
    if not (abs(g0) < 1e5 and abs(g1) < 1e5) or slope >= 0:
        # No clamp / no stable balance nearby: a large, smooth-ish penalty.
        return float(np.sign(g0) * 1e3)
    return float(-g0 / slope)


def predict_engine_rpm(solver: Solver, secondary_rpm: float, secondary_torque_nm: float,
                       guess_rpm: float | None = None) -> tuple[float, str]:
    """Engine rpm where the forces balance at a secondary rpm and load.

    Returns ``(engine_rpm, segment)``; on a stop the stop's ratio sets the
    speed.  The creep efficiency is iterated (twice: it changes ~0.1 %).
    """
    eta = 1.0
    n, seg = float("nan"), "none"
    for _ in range(2):
        a = secondary_rpm * solver.ratio_high_stop / eta * (1 + 1e-9)
        b = secondary_rpm * solver.ratio_low_stop / eta * (1 - 1e-9)

        def g(n_e):
            return _force_residual_n(solver, n_e, secondary_rpm, secondary_torque_nm, eta)[0]

        # g falls with engine rpm (the flyweights' clamp grows as n^2); bracket
        # around the guess first (a neighbour's answer or the measured rpm).
        aa, bb = a, b
        if guess_rpm is not None and a < guess_rpm < b:
            width = 20.0
            while True:
                aa, bb = max(a, guess_rpm - width), min(b, guess_rpm + width)
                ga, gb = g(aa), g(bb)
                if (ga > 0) != (gb > 0) or (aa == a and bb == b):
                    break
                width *= 4.0
        else:
            ga, gb = g(aa), g(bb)
        if (ga > 0) != (gb > 0):
            n, seg = brentq(g, aa, bb, xtol=0.01), "shifting"
        elif ga <= 0:
            n, seg = a, "high_stop"  # the belt would shift past the high stop
        else:
            n, seg = b, "low_stop"   # the secondary wins even at the low stop
        eta = _force_residual_n(solver, n, secondary_rpm, secondary_torque_nm, eta)[1]
        guess_rpm = n
    return float(n), seg


def residual_summary(runs: Sequence[FitRun], parameters: Sequence[float]) -> dict[str, Any]:
    """Exact engine-rpm residuals (measured - predicted) of every point."""
    per_run = []
    all_res, fit_res = [], []
    for run in runs:
        solver = solver_for(run.tune, run.engine, parameters)
        rows = []
        for p in run.points:
            n, seg = predict_engine_rpm(solver, p.secondary_rpm, p.secondary_torque_nm, p.engine_rpm)
            r = p.engine_rpm - n
            stop = on_stop(solver, p)
            rows.append({"engine_rpm": p.engine_rpm, "secondary_rpm": p.secondary_rpm,
                         "secondary_torque_nm": p.secondary_torque_nm, "predicted_engine_rpm": n,
                         "residual_rpm": r, "segment": seg, "used_in_fit": stop is None})
            all_res.append(r)
            if stop is None:
                fit_res.append(r)
        per_run.append({"run": run.name, "tune": run.tune.name, "points": rows})
    a, f = np.asarray(all_res), np.asarray(fit_res)
    return {"runs": per_run, "n": int(a.size), "rms_rpm": float(np.sqrt(np.mean(a ** 2))),
            "max_abs_rpm": float(np.max(np.abs(a))), "mean_rpm": float(np.mean(a)),
            "rms_fit_points_rpm": float(np.sqrt(np.mean(f ** 2))) if f.size else float("nan")}


# ------------------------------------------------------------------ fit


def fit_runs(runs: Sequence[FitRun], initial: Sequence[float] = NOMINAL, report: bool = True) -> FitResult:
    """Least-squares estimate of :data:`PARAMETERS` from logged runs.

    Works in scaled units ``u = (theta - nominal) / SCALE`` so the three
    parameters have comparable steps; the Jacobian is finite-difference
    (``scipy.optimize.least_squares``, trust-region reflective).
    """
    nominal = np.asarray(NOMINAL, dtype=float)
    scale = np.asarray(SCALE, dtype=float)
    items = []  # (run, point, creep eta at nominal) for the points off the stops
    for run in runs:
        s0 = solver_for(run.tune, run.engine, initial)
        for p in run.points:
            if on_stop(s0, p) is None:
                items.append((run, p, _creep_eta(s0, p)))
    n_par = len(PARAMETERS)
    if len(items) <= n_par:
        raise ConfigError("<runs>", "points", f"more than {n_par} steady points off the ratio stops")

    def theta_of(u):
        return nominal + scale * np.asarray(u)

    def residuals(u):
        theta = theta_of(u)
        solvers = {id(run): solver_for(run.tune, run.engine, theta) for run in runs}
        return np.array([newton_residual_rpm(solvers[id(run)], p, eta) for run, p, eta in items])

    u0 = (np.asarray(initial, dtype=float) - nominal) / scale
    # Friction in (0.05, 1): the closed form needs alpha > atan(f) headroom and f > 0.
    lower = (np.array([0.05, -0.02, -20.0]) - nominal) / scale
    upper = (np.array([1.0, 0.02, 20.0]) - nominal) / scale
    sol = least_squares(residuals, u0, bounds=(lower, upper), diff_step=1e-3, x_scale=1.0,
                        xtol=1e-10, ftol=1e-10, gtol=1e-10)
    r = sol.fun
    dof = r.size - n_par
    s2 = float(r @ r) / dof
    jac_u = sol.jac
    cov_u = s2 * np.linalg.inv(jac_u.T @ jac_u)
    cov = cov_u * np.outer(scale, scale)
    sig = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sig, sig)
    theta = theta_of(sol.x)
    before = residual_summary(runs, initial) if report else {}
    after = residual_summary(runs, theta) if report else {}
    return FitResult(
        parameters=dict(zip(PARAMETERS, map(float, theta))), sigma=dict(zip(PARAMETERS, map(float, sig))),
        covariance=cov, correlation=corr, residual_std_rpm=math.sqrt(s2), n_points_fit=int(r.size), dof=dof,
        before=before, after=after,
        optimizer={"status": int(sol.status), "message": sol.message, "nfev": int(sol.nfev),
                   "cost_rpm2": float(sol.cost)})


def format_fit(result: FitResult) -> str:
    """Human-readable fit report."""
    lines = ["fit to the rig (least squares, cov = s^2 (J^T J)^-1):"]
    fmt = {"belt_friction_coefficient": (1.0, "", "{:.4f}"), "flyweight_radius_offset_m": (1e3, "mm", "{:+.3f}"),
           "secondary_friction_torque_nm": (1.0, "N m", "{:+.3f}")}
    for i, name in enumerate(PARAMETERS):
        k, unit, f = fmt[name]
        lines.append(f"  {name:<30} {f.format(result.parameters[name] * k):>9} +- "
                     f"{result.sigma[name] * k:.4f} {unit}   (nominal {NOMINAL[i] * k:g})")
    lines.append(f"  points used {result.n_points_fit} (off the ratio stops), dof {result.dof}, "
                 f"residual std {result.residual_std_rpm:.1f} rpm")
    if result.before and result.after:
        for label, s in (("before", result.before), ("after", result.after)):
            lines.append(f"  engine rpm residual {label:<6}: rms {s['rms_rpm']:7.1f}  max |{s['max_abs_rpm']:.1f}|  "
                         f"mean {s['mean_rpm']:+.1f} rpm  ({s['n']} points)")
    return "\n".join(lines)
