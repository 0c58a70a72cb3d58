"""The tune advisor's model: what a run measured, what a tune predicts, and the calibration between.

**Figures** (what the engagement plan measures, docs/control.md "Characterisation"), each predicted from
a tune with the host's actuator relations (:mod:`dyno.tuning.actuators`) at the belt's measured low stop
(the primary pitch radius whose geometric ratio is the run's ``low_ratio``):

* ``engagement`` at a secondary load ``T``: the belt breaks away when the primary's slip torque
  ``2 mu r_p F_p / sin(alpha)`` (flank friction mu = 0.4, the thesis's f) carries ``T / i_low``, so
  ``F_p(n) = T sin(alpha) / (2 mu r_p i_low)`` with ``F_p`` the flyweights minus the spring (Messick
  eq. 9.3);
* ``shift_out`` at a load ``T``: the belt's thrust ratio times the primary clamp equals the secondary's
  (springs + helix, Sorge eq. 22) at the low stop -- the upshift begins.  The thrust ratio
  ``kappa = F_s,belt / F_p`` is not 1: at no load it is the V-belt statics' limit, the ratio of the wrap
  angles ``theta_s / theta_p`` (1.48 at the 3.0 low stop: the secondary's longer arc needs more thrust for
  the same tensions), and it falls as the belt carries torque.  The belt models disagree on how fast (the
  closed form by ~17 %, Gerbert's capstan by ~60 % at ``T_p / (r_p F_p)`` = 0.4; the thesis's BVP sits
  higher at no load), so the advisor carries an effective ``kappa = (1 + a) (theta_s / theta_p)
  exp(-c T_p / (r_p F_p))`` whose ``a`` and ``c`` are calibrated with the parts (prior a 0 +- 0.3,
  c 1 +- 1), shared by every tune (the belt and the pulleys stay);
* the **friction** the frictionless relations leave out, shared by every tune too (the rig's sheaves,
  ramps and belt stay): an effective flank friction ``mu = FLANK_FRICTION (1 + m)`` (rubber on aluminium:
  prior m 0 +- 0.125, i.e. mu 0.4 +- 0.05) and an effective ramp friction ``h``: the up-shift figures
  (engine speed rising: the sheave closes or starts to shift against the ramps' and rollers' friction)
  see the flyweights' force ``(1 - h) C n^2`` (prior h 0.03 +- 0.03, >= 0).  With ``a, c`` these four are
  the "rig" parameters (:func:`thrust_params`), calibrated from the runs' engagement and shift-out
  figures: one run pins ``mu (1 - h) m_fw`` and ``(1 - h) m_fw`` only through the prior, runs with
  other flyweights or springs separate them;
* ``full_load``: the engine speed of the force balance at the low stop at full throttle
  (:meth:`dyno.tuning.shift_curve.Solver.balance_rpm`, closed-form belt thrusts, the run's engine map).

**Effective parameters**: a part's true values are not its labels. Each part fitted in any given run
(identified by its labelled values, :func:`dyno.tuning.parts.part_identity`) gets a relative deviation
per deviated field (flyweight mass; spring preload and rate; helix angle): true = label x (1 + d).
The prior on ``d`` is the part's stated tolerance as a uniform distribution (sd = tol / sqrt 3);
catalogue parts state it, parts of a run's tune that no catalogue lists get 0.1.

**Calibration**: maximum a posteriori over every ``d`` (``scipy.optimize.least_squares`` on the
whitened residuals: each measured figure over its sigma -- its 95 % interval / 1.96 and a model floor
:data:`MODEL_SD_RPM` in quadrature -- and each ``d`` over its prior sd). The covariance is
``(J^T J)^-1`` of the whitened problem, scaled up by the data's chi^2 per figure when that exceeds 1.
An engagement run pins the combinations the figures see (preload / mass, (preload + secondary
clamp) / mass, the helix / mass across loads); the rest stays at its prior, and the covariance says so.

**Prediction** of a tune: its parts' ``d`` (calibrated where a run saw the part, prior where not:
independent, mean 0), the figure and its Jacobian in ``d`` (central differences); ``u^2 = g^T C g +
MODEL_SD_RPM^2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.optimize import brentq, least_squares

from dyno.errors import ConfigError
from dyno.tuning import actuators as act
from dyno.tuning.parts import DEVIATED, part_identity

#: belt flank friction while it slips at engagement (the thesis's f = 0.4)
FLANK_FRICTION = 0.4
#: model floor per figure (rpm): what the quasi-static relations leave out (ramp lag, creep, losses)
MODEL_SD_RPM = {"engagement": 6.0, "shift_out": 8.0, "full_load": 60.0, "steady": 60.0}
#: a steady run needs this many points off the ratio stops to count (as dyno.tuning.fit's own fit)
MIN_STEADY_POINTS = 4
UNKNOWN_PART_TOLERANCE_REL = 0.1
FIGURES = ("engagement", "shift_out", "full_load")


@dataclass(frozen=True)
class Figure:
    """One measured figure of a run."""

    run: str
    figure: str          # engagement | shift_out | full_load
    load_nm: float       # secondary load it was measured at (full_load: nan)
    rpm: float
    ci95_rpm: float

    @property
    def sigma_rpm(self) -> float:
        ci = self.ci95_rpm if math.isfinite(self.ci95_rpm) else 10.0
        return math.hypot(ci / 1.96, MODEL_SD_RPM[self.figure])


@dataclass
class RunData:
    name: str
    path: Path
    tune: object
    low_ratio: float
    figures: list[Figure]
    engine: object = None   # EngineMap (full_load and steady points)
    light_load_nm: float = 0.2
    steady: list = field(default_factory=list)  # dyno.tuning.fit.MeasuredPoint, off the ratio stops
    full_shift_ratio: float = math.nan  # the engagement plan's high stop (creep included)


def _f(x) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return math.nan
    return v


def load_run_data(run_dir) -> RunData:
    """An engagement run's measured figures (never its ``*_true`` entries: those are the sim's secret)."""
    from dyno.runlog.reader import load_run
    from dyno.tuning.tune import load_tune

    run_dir = Path(run_dir)
    run = load_run(run_dir, with_events=False)
    if not (run_dir / "tune.toml").exists():
        raise ConfigError(run_dir, "tune.toml", "the run's tune (dyno run --tune stores it)")
    tune = load_tune(run_dir / "tune.toml")
    chars = run.docs("characterisation")
    figs: list[Figure] = []
    low = high = math.nan
    if chars:
        c = chars[-1]
        low, high = _f(c.get("low_ratio")), _f(c.get("full_shift_ratio"))
        rows = c.get("shift_out_vs_load") or [{"torque_secondary_nm": c.get("shift_out_torque_nm"),
                                               "engagement_rpm": c.get("engagement_rpm"),
                                               "shift_out_rpm": c.get("shift_out_rpm"),
                                               "shift_out_rpm_ci95": c.get("shift_out_rpm_ci95")}]
        eng_ci = _f(c.get("engagement_rpm_ci95"))
        for r in rows:
            t = _f(r.get("torque_secondary_nm"))
            if not math.isfinite(t):
                continue
            if math.isfinite(_f(r.get("engagement_rpm"))):
                figs.append(Figure(run_dir.name, "engagement", t, _f(r["engagement_rpm"]), eng_ci))
            if math.isfinite(_f(r.get("shift_out_rpm"))):
                figs.append(Figure(run_dir.name, "shift_out", t, _f(r["shift_out_rpm"]),
                                   _f(r.get("shift_out_rpm_ci95"))))
    steady = _steady_points(run, tune)
    if (not figs or not math.isfinite(low)) and len(steady) < MIN_STEADY_POINTS:
        raise ConfigError(run_dir, "characterisation", "an engagement run's engagement and shift-out with the "
                                                       f"low-gear ratio, or >= {MIN_STEADY_POINTS} steady points "
                                                       "off the ratio stops (a speed-hold or sweep run)")
    engine = None
    if run.engine_map_path is not None and Path(run.engine_map_path).exists():
        from dyno.tuning.shift_curve import load_engine_map

        engine = load_engine_map(run.engine_map_path)
    light = min((f.load_nm for f in figs), default=0.2)
    if steady and engine is None:
        raise ConfigError(run_dir, "engine_map.csv", "the run's engine map (its steady points need it)")
    return RunData(run_dir.name, run_dir, tune, low, figs, engine, light, steady, high)


def _steady_points(run, tune) -> list:
    """A steady run's valid points off the tune's ratio stops (the stop, not the balance, sets those)."""
    from dyno.tuning.fit import MeasuredPoint

    lo = hi = None
    out = []
    for p in run.points:
        n_e, n_s, t = (_f(p.get(k)) for k in ("rpm_primary", "rpm_secondary", "torque_secondary_nm"))
        if not (p.get("valid", True) and all(math.isfinite(v) for v in (n_e, n_s, t)) and n_s > 0):
            continue
        if lo is None:
            from dyno.tuning.shift_curve import Solver
            from dyno.tuning.tune import model_params_for

            s = Solver(tune, None, model_params_for(tune))
            lo, hi = s.ratio_low_stop, s.ratio_high_stop
        ratio = n_e / n_s
        if hi * 1.01 < ratio < lo * 0.99:
            out.append(MeasuredPoint(n_e, n_s, t))
    return out


# ------------------------------------------------------------------ forward model


def low_stop_radii_m(tune, low_ratio: float) -> tuple[float, float]:
    """(primary, secondary) pitch radius where the geometric ratio is ``low_ratio`` (clipped to the travel)."""
    return _radii(tune.drive, round(float(low_ratio), 9))


@lru_cache(maxsize=256)
def _radii(d, low_ratio: float) -> tuple[float, float]:
    from dyno.tuning.tune import Tune

    tune = Tune("geometry", d, None, None, None)  # the radii depend on the drive alone

    def g(r):
        return float(act.secondary_radius_m(tune, r)) / r - low_ratio

    a, b = d.primary_radius_min_m, d.primary_radius_max_m
    if g(a) <= 0:
        r = a
    elif g(b) >= 0:
        r = b
    else:
        r = brentq(g, a, b, xtol=1e-9)
    return r, float(act.secondary_radius_m(tune, r))


#: the rig's effective parameters (module docstring): the thrust ratio's level a and decay c, the flank
#: friction's relative deviation m and the ramps' friction h; nominal values and prior sds
THRUST_NOMINAL = (0.0, 1.0, 0.0, 0.03)
THRUST_PRIOR_SD = (0.3, 1.0, 0.125, 0.03)
THRUST_FIELDS = ("kappa_level", "kappa_decay", "flank_friction_rel", "ramp_friction")
#: their bounds as deviations from nominal (c >= 0, h >= 0)
THRUST_BOUNDS = ((-0.9, math.inf), (-1.0, math.inf), (-0.4, 0.4), (-0.03, 0.17))


def wrap_ratio(tune, low_ratio: float) -> float:
    """theta_s / theta_p at the low stop: the thrust ratio of a V-belt at no load."""
    from dyno.model.geometry import wrap_angles_rad

    r_p, r_s = low_stop_radii_m(tune, low_ratio)
    phi_p, phi_s = wrap_angles_rad(r_p, r_s, tune.drive.centre_distance_m)
    return float(phi_s / phi_p)


def primary_force_for_secondary_n(f_s: float, torque_primary_nm: float, r_p: float, kappa0: float,
                                  decay: float) -> float:
    """The primary clamp ``F`` with ``F kappa0 exp(-decay T_p / (r_p F)) = f_s`` (increasing in F: one root
    in [f_s / kappa0, f_s / kappa0 + decay T_p / r_p], since e^-x >= 1 - x)."""
    a = f_s / kappa0
    k = max(decay, 0.0) * max(torque_primary_nm, 0.0) / r_p
    if a <= 0.0 or k == 0.0:
        return a
    g = lambda f: f * math.exp(-k / f) - a  # noqa: E731
    hi = a + 2.0 * k + 1e-6  # (a + k would do exactly; the margin keeps the sign under rounding)
    if g(a) >= 0.0:
        return a
    return float(brentq(g, a, hi, xtol=1e-6))


def predict_figure(tune, figure: str, load_nm: float, low_ratio: float, engine=None, theta=None,
                   thrust=None) -> float:
    """A figure of ``tune`` (the true or effective values) at a secondary load; ``theta``: the closed-form
    shift model's effective (f, dr, T_fr) of :mod:`dyno.tuning.fit` for the full-load figure; ``thrust``:
    the effective thrust ratio's (a, c) for the shift-out (None: nominal)."""
    r_p, r_s = low_stop_radii_m(tune, low_ratio)
    a, c, m, h = THRUST_NOMINAL if thrust is None else tuple(thrust) + THRUST_NOMINAL[len(thrust):]
    if figure in ("engagement", "shift_out") and h and tune.flyweights is not None:
        # the up-shift's ramp friction: (1 - h) of the flyweights' force, as a (1 - h) lighter set
        tune = tune.with_changes(**{"flyweights.mass_each_kg": tune.flyweights.mass_each_kg * (1.0 - h)})
    if figure == "engagement":
        sin_a = math.sin(math.radians(tune.drive.sheave_half_angle_deg))
        f_need = max(load_nm, 0.0) * sin_a / (2.0 * FLANK_FRICTION * (1.0 + m) * r_p * low_ratio)
        return float(act.primary_speed_for_force_rpm(tune, f_need, r_p))
    if figure == "shift_out":
        f_s = float(act.secondary_axial_force_n(tune, max(load_nm, 0.0), r_s))
        f_p = primary_force_for_secondary_n(f_s, max(load_nm, 0.0) / low_ratio, r_p,
                                            (1.0 + a) * wrap_ratio(tune, low_ratio), c)
        return float(act.primary_speed_for_force_rpm(tune, f_p, r_p))
    if figure == "full_load":
        if engine is None:
            return math.nan
        from dyno.tuning.fit import NOMINAL, solver_for

        return float(solver_for(tune, engine, NOMINAL if theta is None else theta).balance_rpm(low_ratio))
    raise ValueError(figure)


# ------------------------------------------------------------------ parameters


@dataclass(frozen=True)
class Param:
    part: str       # part identity
    kind: str       # tune attribute
    field: str
    prior_sd: float


#: the closed-form shift model's effective parameters (dyno.tuning.fit), calibrated when steady points are
#: given: they take the belt thrust model's error, so the parts' deviations do not have to. Prior sd in the
#: fit's scaled units (f 0.1, dr 3 mm, T_fr 2 N m).
BELT_PRIOR_SD_SCALED = (2.0, 3.0, 4.0)


def belt_params() -> list[Param]:
    from dyno.tuning.fit import PARAMETERS

    return [Param("belt", "belt", name, sd) for name, sd in zip(PARAMETERS, BELT_PRIOR_SD_SCALED)]


def thrust_params() -> list[Param]:
    """The rig's effective parameters shared by every tune: the thrust ratio's and the friction's."""
    return [Param("belt", "thrust", name, sd) for name, sd in zip(THRUST_FIELDS, THRUST_PRIOR_SD)]


def thrust_of(d_thrust) -> tuple[float, float]:
    return tuple(n + float(x) for n, x in zip(THRUST_NOMINAL, d_thrust))


def theta_of(d_belt) -> list[float]:
    from dyno.tuning.fit import NOMINAL, SCALE

    return [n + s * float(x) for n, s, x in zip(NOMINAL, SCALE, d_belt)]


def tune_params(tune, tolerance_of) -> list[Param]:
    """The deviated fields of a tune's parts; ``tolerance_of(identity, kind)`` gives a part's tolerance."""
    out = []
    for kind, fields in DEVIATED.items():
        if getattr(tune, kind, None) is None:
            continue
        ident = part_identity(tune, kind)
        tol = tolerance_of(ident, kind)
        out.extend(Param(ident, kind, f, tol / math.sqrt(3.0)) for f in fields)
    return out


def effective_tune(tune, params: list[Param], d: np.ndarray):
    changes = {}
    for p, x in zip(params, d):
        obj = getattr(tune, p.kind)
        label = getattr(obj, p.field)
        if p.kind == "flyweights" and p.field == "mass_each_kg":
            # the deviation is the body's; tuning washers are weighed (their +-2 % is in the model floor)
            changes["flyweights.mass_each_kg"] = obj.body_mass_each_kg * (1.0 + float(x)) + obj.washer_mass_each_kg
            continue
        changes[f"{p.kind}.{p.field}"] = label * (1.0 + float(x))
    return tune.with_changes(**changes) if changes else tune


@dataclass
class Calibration:
    params: list[Param]                  # every part seen in the runs
    d: np.ndarray                        # MAP deviations
    cov: np.ndarray
    chi2_per_figure: float
    n_figures: int
    residuals: list[dict] = field(default_factory=list)

    def index(self) -> dict[tuple[str, str], int]:
        return {(p.part, p.field): i for i, p in enumerate(self.params)}

    def to_dict(self) -> dict:
        sd = np.sqrt(np.diag(self.cov)) if self.cov.size else np.array([])
        return {"parameters": [{"part": p.part, "field": p.field, "deviation_rel": float(x),
                                "u_rel": float(s), "prior_sd_rel": p.prior_sd}
                               for p, x, s in zip(self.params, self.d, sd)],
                "chi2_per_figure": self.chi2_per_figure, "n_figures": self.n_figures,
                "residuals": self.residuals}


def calibrate(runs: list[RunData], tolerance_of) -> Calibration:
    """MAP deviations of every part the runs saw, with their covariance (see the module docstring)."""
    params: list[Param] = []
    seen = set()
    per_run = []
    for r in runs:
        ps = tune_params(r.tune, tolerance_of)
        for p in ps:
            if (p.part, p.field) not in seen:
                seen.add((p.part, p.field))
                params.append(p)
        per_run.append(ps)
    if any(r.steady for r in runs):
        params.extend(belt_params())
    with_thrust = any(f.figure in ("engagement", "shift_out") for r in runs for f in r.figures)
    if with_thrust:
        params.extend(thrust_params())
    idx = {(p.part, p.field): i for i, p in enumerate(params)}
    prior = np.array([p.prior_sd for p in params])

    from dyno.tuning.fit import newton_residual_rpm, solver_for

    def model(d):
        out = []
        thrust = thrust_of([d[idx[(p.part, p.field)]] for p in thrust_params()]) if with_thrust else None
        for r, ps in zip(runs, per_run):
            t = effective_tune(r.tune, ps, np.array([d[idx[(p.part, p.field)]] for p in ps]))
            out.extend(predict_figure(t, f.figure, f.load_nm, r.low_ratio, r.engine, thrust=thrust)
                       for f in r.figures)
        return np.array(out)

    def steady(d):
        # measured minus predicted engine rpm at each steady point's secondary rpm and load (Newton step of
        # dyno.tuning.fit: the closed-form balance with the effective parts, the run's engine map)
        out = []
        theta = theta_of([d[idx[(p.part, p.field)]] for p in belt_params()])
        for r, ps in zip(runs, per_run):
            if r.steady:
                t = effective_tune(r.tune, ps, np.array([d[idx[(p.part, p.field)]] for p in ps]))
                sv = solver_for(t, r.engine, theta)
                out.extend(newton_residual_rpm(sv, p) for p in r.steady)
        return np.array(out)

    lows = [r.low_ratio for r in runs if math.isfinite(r.low_ratio)]
    highs = [r.full_shift_ratio for r in runs if math.isfinite(r.full_shift_ratio)]
    # an engagement run measured the rig's ratio stops: steady points on them carry no balance
    for r in runs:
        r.steady = [p for p in r.steady if (not lows or p.engine_rpm / p.secondary_rpm < 0.99 * max(lows))
                    and (not highs or p.engine_rpm / p.secondary_rpm > 1.01 * min(highs))]
    meas = np.array([f.rpm for r in runs for f in r.figures])
    sig = np.array([f.sigma_rpm for r in runs for f in r.figures])
    n_steady = sum(len(r.steady) for r in runs)
    steady_sd = [MODEL_SD_RPM["steady"]]

    def resid(d):
        pred = model(d)
        pred = np.where(np.isfinite(pred), pred, meas + 1e4)
        parts = [(meas - pred) / sig]
        if n_steady:
            parts.append(steady(d) / steady_sd[0])
        return np.concatenate(parts + [d / prior])

    # a part's deviation cannot leave its stated tolerance (the uniform prior's support)
    # (the thrust ratio's decay cannot turn into growth: c >= 0)
    bound = np.array([p.prior_sd * math.sqrt(3.0) if p.kind not in ("belt", "thrust") else np.inf for p in params])
    lower = -bound.copy()
    for i, p in enumerate(params):
        if p.kind == "thrust":
            lower[i], bound[i] = THRUST_BOUNDS[THRUST_FIELDS.index(p.field)]
    x0 = np.zeros(len(params))
    sol = least_squares(resid, x0, bounds=(lower, bound), diff_step=1e-4, xtol=1e-10, ftol=1e-10)
    if n_steady:
        # the steady points' scatter about the closed form is model error, not noise: weigh them by the
        # scatter they show (at least the floor), once, so they cannot outvote the engagement figures
        rms = float(np.sqrt(np.mean(steady(sol.x) ** 2)))
        if rms > steady_sd[0]:
            steady_sd[0] = rms
            sol = least_squares(resid, sol.x, bounds=(lower, bound), diff_step=1e-4, xtol=1e-10, ftol=1e-10)
    j = sol.jac
    cov = np.linalg.inv(j.T @ j)
    # the engagement figures' chi^2 per figure scales the covariance up when their scatter exceeds their sigmas
    r_fig = sol.fun[:meas.size]
    chi2 = float(r_fig @ r_fig) / max(meas.size, 1) if meas.size else 1.0
    if chi2 > 1.0:
        cov = cov * chi2
    pred = model(sol.x)
    rows = [{"run": f.run, "figure": f.figure, "load_nm": f.load_nm, "measured_rpm": f.rpm,
             "calibrated_rpm": float(p), "residual_rpm": float(f.rpm - p)}
            for f, p in zip([f for r in runs for f in r.figures], pred)]
    if n_steady:
        rows += [{"run": r.name, "figure": "steady", "secondary_rpm": p.secondary_rpm, "load_nm": p.secondary_torque_nm,
                  "measured_rpm": p.engine_rpm, "residual_rpm": float(x)}
                 for r, p, x in zip([r for r in runs for _ in r.steady], [p for r in runs for p in r.steady],
                                    steady(sol.x))]
    return Calibration(params, sol.x, cov, chi2, int(meas.size + n_steady), rows)


def predict_with_u(cal: Calibration, tune, figure: str, load_nm: float, low_ratio: float, tolerance_of,
                   engine=None, step: float = 1e-3) -> tuple[float, float]:
    """(figure, standard uncertainty) of ``tune`` with the calibrated (or prior) part deviations."""
    ps = tune_params(tune, tolerance_of)
    idx = cal.index()
    n_part = len(ps)
    if figure == "full_load" and ("belt", belt_params()[0].field) in idx:
        ps = ps + belt_params()  # the calibrated shift model's effective parameters
    if figure in ("engagement", "shift_out"):
        ps = ps + thrust_params()  # calibrated if a run measured these figures, else at their prior
    d = np.array([cal.d[idx[(p.part, p.field)]] if (p.part, p.field) in idx else 0.0 for p in ps])

    def f(x):
        extra = x[n_part:]
        theta = theta_of(extra) if figure == "full_load" and len(ps) > n_part else None
        thrust = thrust_of(extra) if figure in ("engagement", "shift_out") else None
        return predict_figure(effective_tune(tune, ps[:n_part], x[:n_part]), figure, load_nm, low_ratio, engine,
                              theta, thrust)

    y0 = f(d)
    if not math.isfinite(y0):
        return math.nan, math.nan
    g = np.zeros(len(ps))
    for i in range(len(ps)):
        dp, dm = d.copy(), d.copy()
        dp[i] += step
        dm[i] -= step
        g[i] = (f(dp) - f(dm)) / (2 * step)
    seen = [i for i, p in enumerate(ps) if (p.part, p.field) in idx]
    new = [i for i, p in enumerate(ps) if (p.part, p.field) not in idx]
    var = MODEL_SD_RPM[figure] ** 2
    if seen:
        ci = [idx[(ps[i].part, ps[i].field)] for i in seen]
        gs = g[seen]
        var += float(gs @ cal.cov[np.ix_(ci, ci)] @ gs)
    for i in new:
        var += (g[i] * ps[i].prior_sd) ** 2
    return float(y0), math.sqrt(var)


def _calibrated(cal: Calibration, params: list[Param], convert):
    idx = cal.index()
    if (params[0].part, params[0].field) not in idx:
        return None
    return convert([cal.d[idx[(p.part, p.field)]] for p in params])


def calibrated_theta(cal: Calibration):
    """The calibrated (f, dr, T_fr) when steady points were given, else None (the nominal model)."""
    return _calibrated(cal, belt_params(), theta_of)


def calibrated_thrust(cal: Calibration):
    """The calibrated rig parameters (a, c, m, h) when a run measured the light figures, else None (nominal)."""
    return _calibrated(cal, thrust_params(), thrust_of)
