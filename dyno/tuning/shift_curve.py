"""Predicted steady shift curve of a mechanical CVT from its tune.

At a steady operating point three things hold at once:

1. the primary actuator's clamp ``F_p(n_e, r_p)`` (flyweights minus spring,
   :func:`dyno.tuning.actuators.primary_axial_force_n`) is the belt's primary
   thrust -- it sets the belt tension level through the closed-form driver
   thrust (Sorge & Cammalleri eq. 17, in :mod:`dyno.model.closed_form`);
2. the belt then *requires* a definite secondary thrust (eq. 18); the
   secondary actuator (springs + helix, eq. 22) must supply exactly that;
3. the engine runs on its full-throttle map, ``M_p = T_e(n_e)``, and the
   secondary torque is ``M_s = M_p R eta_T`` (the load that holds the point).

For each geometric ratio ``R = r_s/r_p`` between the stops, (1)-(3) leave
one unknown, the engine speed, found with Brent's method on the secondary
force residual ``F_s,act - F_s,belt``.  The sweep gives engine rpm vs
secondary rpm; the low-ratio stop (before the upshift) and the high-ratio
stop (full shift) add the two straight segments through the origin.

Derived figures:

* ``engagement_rpm`` -- engine speed at which the flyweights overcome the
  primary spring preload at the low stop (the sheave starts to clamp);
* ``shift_out_rpm`` -- engine speed at which the upshift begins (force
  balance at the low stop), the rpm a well-tuned CVT then holds;
* ``full_shift_rpm`` -- engine speed on reaching the high stop.

Pure functions; :func:`load_engine_map` is the only file reader.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.optimize import brentq

from dyno.errors import ConfigError, DidNotConverge
from dyno.model.closed_form import closed_form_point
from dyno.model.params import ModelParams, OperatingPoint
from dyno.tuning import actuators as act
from dyno.tuning.tune import Tune, model_params_for



# ------------------------------------------------------------- engine map


@dataclass(frozen=True)
class EngineMap:
    """Full-throttle engine torque vs speed (PCHIP; held flat outside)."""

    speed_rpm: tuple[float, ...]
    torque_nm: tuple[float, ...]
    name: str = ""

    def __post_init__(self):
        if len(self.speed_rpm) < 2 or any(b <= a for a, b in zip(self.speed_rpm, self.speed_rpm[1:])):
            raise ConfigError(self.name or "<engine map>", "rpm", "at least 2 strictly increasing speeds")

    @property
    def _interp(self) -> PchipInterpolator:
        interp = self.__dict__.get("_pchip")
        if interp is None:
            interp = PchipInterpolator(np.asarray(self.speed_rpm), np.asarray(self.torque_nm), extrapolate=False)
            object.__setattr__(self, "_pchip", interp)
        return interp

    def torque_at_nm(self, speed_rpm):
        s = np.clip(np.asarray(speed_rpm, dtype=float), self.speed_rpm[0], self.speed_rpm[-1])
        out = self._interp(s)
        return out if np.ndim(out) else float(out)

    @property
    def max_speed_rpm(self) -> float:
        return self.speed_rpm[-1]


def load_engine_map(path: str | Path) -> EngineMap:
    """Read an engine-map CSV with the host's loaders (``dyno.analysis.engine_map``).

    A headed file (``rpm,torque_nm`` / ``rpm,power_hp`` / ``rpm,power_kw``) or the
    thesis's header-less ``rpm,hp`` file.  Here the map is *held flat* outside its
    range (a shift-curve sweep brackets roots beyond it), unlike the host's
    efficiency computation, which refuses to extrapolate.
    """
    from dyno.analysis import engine_map as em

    path = Path(path)
    try:
        first = next((ln for ln in path.read_text(encoding="utf-8").splitlines()
                      if ln.strip() and not ln.startswith("#")), "")
    except OSError as exc:
        raise ConfigError(path, "<file>", f"a readable engine map ({exc.strerror})") from None
    try:
        float(first.split(",")[0])
        m = em.load_legacy_engine_map(path)  # header-less: the thesis's rpm,hp
    except ValueError:
        m = em.load_engine_map(path)
    return EngineMap(tuple(float(x) for x in m.rpm), tuple(float(x) for x in m.torque_nm_knots), str(path))


# ------------------------------------------------------------ belt params


# ------------------------------------------------------------ point solve


@lru_cache(maxsize=4096)
def _primary_radius_m(ratio: float, pitch_length_m: float, centre_distance_m: float) -> float:
    from dyno.model.geometry import radii_for_ratio

    return radii_for_ratio(ratio, pitch_length_m, centre_distance_m)[0]


@dataclass(frozen=True)
class ShiftPoint:
    """One predicted steady operating point."""

    ratio: float  # geometric r_s / r_p
    engine_rpm: float
    secondary_rpm: float
    engine_torque_nm: float
    secondary_torque_nm: float
    primary_radius_m: float
    secondary_radius_m: float
    primary_force_n: float  # actuator = belt
    secondary_force_actuator_n: float
    secondary_force_belt_n: float
    efficiency: float
    segment: str  # "low_stop", "shifting", "high_stop"

    @property
    def force_residual_n(self) -> float:
        return self.secondary_force_actuator_n - self.secondary_force_belt_n


@dataclass(frozen=True)
class Solver:
    """Bundles what every point needs; cheap to build."""

    tune: Tune
    engine: EngineMap
    params: ModelParams
    closing: bool | None = None  # eq. 11 phase; None = steady equal split
    secondary_friction_torque_nm: float = 0.0  # loss on the secondary shaft (fit parameter)
    flyweight_radius_offset_m: float = 0.0  # effective flyweight radius offset (fit parameter)

    # -- pieces
    def primary_force_n(self, engine_rpm: float, primary_radius_m: float) -> float:
        f = act.primary_axial_force_n(self.tune, engine_rpm, primary_radius_m)
        if self.flyweight_radius_offset_m and self.tune.flyweights is not None:
            # dF/dr at fixed dr/dz: an offset of the radius table adds n m dr/dz w^2 offset
            z = act.primary_sheave_travel_m(self.tune, primary_radius_m)
            _, drdz = act.flyweight_radius_m(self.tune.flyweights, z)
            w = engine_rpm * act.RPM_TO_RAD_S
            fw = self.tune.flyweights
            f += float(fw.count * fw.mass_each_kg * self.flyweight_radius_offset_m * drdz * w * w)
        return float(f)

    def evaluate(self, ratio: float, engine_rpm: float):
        """Closed-form belt state at (ratio, engine rpm); None if the primary
        clamp cannot carry the engine torque (belt would slip)."""
        r_p = self.primary_radius_for_ratio(ratio)
        m_e = float(self.engine.torque_at_nm(engine_rpm))
        f_p = self.primary_force_n(engine_rpm, r_p)
        if m_e <= 0 or f_p <= 0:
            return None
        op = OperatingPoint(ratio=ratio, primary_speed_rpm=engine_rpm, primary_torque_nm=m_e,
                            slack_tension_n=None, primary_axial_force_n=f_p)
        try:
            res = closed_form_point(self.params, op)
        except (ConfigError, DidNotConverge):
            return None
        m_s = m_e * res.r_secondary_m / res.r_primary_m * res.efficiency_torque
        f_s_act = float(act.secondary_axial_force_n(self.tune, m_s, res.r_secondary_m, closing=self.closing))
        return res, m_e, m_s, f_p, f_s_act

    def residual_n(self, ratio: float, engine_rpm: float) -> float:
        """Secondary actuator minus belt requirement; > 0 pushes toward low ratio."""
        ev = self.evaluate(ratio, engine_rpm)
        if ev is None:
            return 1e6  # primary cannot hold the belt: the secondary wins
        res, _, _, _, f_s_act = ev
        return f_s_act - res.axial_force_secondary_n

    def primary_radius_for_ratio(self, ratio: float) -> float:
        return _primary_radius_m(ratio, self.params.belt.pitch_length_m, self.params.drive.centre_distance_m)

    @property
    def ratio_low_stop(self) -> float:
        d = self.tune.drive
        return act.secondary_radius_closed_m(self.tune) / d.primary_radius_min_m

    @property
    def ratio_high_stop(self) -> float:
        d = self.tune.drive
        return float(act.secondary_radius_m(self.tune, d.primary_radius_max_m)) / d.primary_radius_max_m

    def balance_rpm(self, ratio: float, guess_rpm: float | None = None) -> float:
        """Engine speed at which the forces balance at ``ratio`` (NaN if none
        inside the engine map).  ``guess_rpm`` (the neighbouring point's
        answer) narrows the bracket, which halves the closed-form calls."""
        lo = self.engine.speed_rpm[0] * 0.5
        hi = self.engine.max_speed_rpm
        if guess_rpm is not None and lo < guess_rpm < hi:
            width = 50.0
            while width < hi - lo:
                a, b = max(lo, guess_rpm - width), min(hi, guess_rpm + width)
                fa, fb = self.residual_n(ratio, a), self.residual_n(ratio, b)
                if fa > 0 >= fb:
                    return brentq(lambda n: self.residual_n(ratio, n), a, b, xtol=0.01)
                width *= 4.0
        f_lo, f_hi = self.residual_n(ratio, lo), self.residual_n(ratio, hi)
        if f_lo < 0:
            return lo  # already shifted at the bottom of the range
        if f_hi > 0:
            # the governor cuts torque near the top; scan down for a sign change
            grid = np.linspace(lo, hi, 25)
            vals = [self.residual_n(ratio, n) for n in grid]
            idx = [k for k in range(len(grid) - 1) if vals[k] > 0 >= vals[k + 1]]
            if not idx:
                return float("nan")
            lo, hi = grid[idx[0]], grid[idx[0] + 1]
        return brentq(lambda n: self.residual_n(ratio, n), lo, hi, xtol=0.01)

    def point(self, ratio: float, engine_rpm: float, segment: str) -> ShiftPoint:
        ev = self.evaluate(ratio, engine_rpm)
        if ev is None:
            raise DidNotConverge(f"no belt state at ratio {ratio:.3f}, {engine_rpm:.0f} rpm")
        res, m_e, m_s, f_p, f_s_act = ev
        m_s_out = max(m_s - self.secondary_friction_torque_nm, 0.0)
        eff = res.efficiency_overall * (m_s_out / m_s if m_s > 0 else 0.0)
        return ShiftPoint(
            ratio=ratio, engine_rpm=engine_rpm,
            secondary_rpm=engine_rpm / ratio * res.efficiency_speed,
            engine_torque_nm=m_e, secondary_torque_nm=m_s_out,
            primary_radius_m=res.r_primary_m, secondary_radius_m=res.r_secondary_m,
            primary_force_n=f_p, secondary_force_actuator_n=f_s_act,
            secondary_force_belt_n=res.axial_force_secondary_n, efficiency=eff, segment=segment)

    def engagement_rpm(self) -> float:
        """Engine rpm at which the flyweights first overcome the primary
        spring preload at the low stop (net clamp = 0): the moving sheave
        starts to pinch the belt."""
        r_p = self.tune.drive.primary_radius_min_m
        lo, hi = 1.0, 2.0 * self.engine.max_speed_rpm
        f = lambda n: self.primary_force_n(n, r_p)  # noqa: E731
        if f(hi) <= 0:
            return float("nan")
        return brentq(f, lo, hi, xtol=0.01)


# ----------------------------------------------------------------- curve


@dataclass
class ShiftCurve:
    tune_name: str
    points: list[ShiftPoint]
    engagement_rpm: float
    shift_out_rpm: float
    full_shift_rpm: float
    ratio_low_stop: float
    ratio_high_stop: float
    sensitivities: dict[str, dict[str, float]] = field(default_factory=dict)
    #: balances the CVT jumps over: along the sweep the secondary speed falls there (a flyweight profile
    #: whose clamp grows with travel faster than the secondary's), so the drive cannot sit on them
    jumped: list[ShiftPoint] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        keys = ("ratio", "engine_rpm", "secondary_rpm", "engine_torque_nm", "secondary_torque_nm",
                "efficiency", "primary_force_n", "secondary_force_actuator_n", "secondary_force_belt_n")
        return {k: np.array([getattr(p, k) for p in self.points]) for k in keys}

    def to_dict(self) -> dict[str, Any]:
        return {
            "tune": self.tune_name,
            "engagement_rpm": self.engagement_rpm,
            "shift_out_rpm": self.shift_out_rpm,
            "full_shift_rpm": self.full_shift_rpm,
            "ratio_low_stop": self.ratio_low_stop,
            "ratio_high_stop": self.ratio_high_stop,
            "sensitivities": self.sensitivities,
            "points": [{**p.__dict__} for p in self.points],
        }


def predict_shift_curve(tune: Tune, engine: EngineMap, n_points: int = 50, params: ModelParams | None = None,
                        closing: bool | None = None, with_stops: bool = True, **solver_kw) -> ShiftCurve:
    """Sweep the steady operating points of a tune.

    ``n_points`` ratios are spaced evenly in log-ratio between the stops
    (each one is a load point: the secondary torque that holds it is
    reported).  With ``with_stops`` a few points are added along the low
    stop (engagement -> shift-out) and the high stop (full shift -> governed
    speed).
    """
    solver = Solver(tune, engine, params or model_params_for(tune), closing=closing, **solver_kw)
    r_lo, r_hi = solver.ratio_low_stop, solver.ratio_high_stop
    ratios = np.exp(np.linspace(math.log(r_lo), math.log(r_hi), n_points))
    pts: list[ShiftPoint] = []
    prev = None
    for R in ratios:
        n = solver.balance_rpm(float(R), prev)
        if math.isnan(n):
            continue
        pts.append(solver.point(float(R), n, "shifting"))
        prev = n
    pts, jumped = _stable_branch(pts)
    shift_out = pts[0].engine_rpm if pts else float("nan")
    full_shift = pts[-1].engine_rpm if pts else float("nan")
    engagement = solver.engagement_rpm()
    if with_stops and pts:
        lows = []
        if not math.isnan(engagement) and engagement < shift_out:
            for n in np.linspace(max(engagement, engine.speed_rpm[0] * 0.5), shift_out, 6)[:-1]:
                ev = solver.evaluate(r_lo, float(n))
                if ev is not None:
                    lows.append(solver.point(r_lo, float(n), "low_stop"))
        highs = []
        for n in np.linspace(full_shift, engine.max_speed_rpm, 6)[1:]:
            if engine.torque_at_nm(float(n)) > 0 and solver.evaluate(r_hi, float(n)) is not None:
                highs.append(solver.point(r_hi, float(n), "high_stop"))
        pts = lows + pts + highs
    del prev
    return ShiftCurve(tune.name, pts, engagement, shift_out, full_shift, r_lo, r_hi, jumped=jumped)


def _stable_branch(pts: list) -> tuple[list, list]:
    """(the balances the drive can sit on, the ones it jumps over), the sweep running low -> high gear.

    Along a stable shift curve the secondary turns faster as the ratio falls.  Where the primary's clamp
    grows with travel faster than the secondary's (a steep start of a flyweight profile), the balance's
    engine speed falls so fast that the secondary's does too: a fold, whose inner branch is unstable (a
    little more travel raises the clamp above the balance: the sheave snaps on).  Kept: each point whose
    secondary speed exceeds every one before it."""
    keep, jumped, top = [], [], -math.inf
    for p in pts:
        if p.secondary_rpm > top:
            keep.append(p)
            top = p.secondary_rpm
        else:
            jumped.append(p)
    return keep, jumped


def key_speeds_rpm(tune: Tune, engine: EngineMap, params: ModelParams | None = None,
                   **solver_kw) -> dict[str, float]:
    """Engagement, shift-out and full-shift rpm only (cheap: three solves)."""
    solver = Solver(tune, engine, params or model_params_for(tune), **solver_kw)
    return {"engagement_rpm": solver.engagement_rpm(),
            "shift_out_rpm": solver.balance_rpm(solver.ratio_low_stop),
            "full_shift_rpm": solver.balance_rpm(solver.ratio_high_stop)}


#: (dotted tune field, step, unit label, scale from SI step to the label unit)
SENSITIVITY_PARAMETERS: tuple[tuple[str, float, str, float], ...] = (
    ("flyweights.mass_each_kg", 0.005, "rpm/g", 1e-3),
    ("primary_spring.preload_n", 20.0, "rpm/N", 1.0),
    ("primary_spring.rate_n_per_m", 1000.0, "rpm/(N/mm)", 1e3),
    ("secondary_spring.preload_n", 20.0, "rpm/N", 1.0),
    ("secondary_spring.rate_n_per_m", 500.0, "rpm/(N/mm)", 1e3),
    ("secondary_spring.torsion_preload_nm", 0.2, "rpm/(N m)", 1.0),
    ("helix.angle_from_axis_deg", 1.0, "rpm/deg", 1.0),
    ("helix.radius_m", 0.002, "rpm/mm", 1e-3),
)


def sensitivities(tune: Tune, engine: EngineMap, params: ModelParams | None = None,
                  parameters=SENSITIVITY_PARAMETERS, **solver_kw) -> dict[str, dict[str, float]]:
    """Central-difference sensitivity of the key speeds to each tune field.

    Returns ``{field: {"unit": ..., "engagement_rpm": d, "shift_out_rpm": d,
    "full_shift_rpm": d}}`` in the labelled unit (e.g. rpm per gram).
    """
    params = params or model_params_for(tune)
    out: dict[str, dict[str, float]] = {}
    for dotted, step, unit, scale in parameters:
        obj = tune
        for part in dotted.split("."):
            obj = getattr(obj, part, None) if obj is not None else None
        if obj is None:
            continue  # e.g. flyweights on a roller-track tune
        hi = key_speeds_rpm(tune.with_changes(**{dotted: obj + step}), engine, params, **solver_kw)
        lo = key_speeds_rpm(tune.with_changes(**{dotted: obj - step}), engine, params, **solver_kw)
        out[dotted] = {"unit": unit, **{k: (hi[k] - lo[k]) / (2 * step) * scale for k in hi}}
    return out


def predicted_engine_rpm_at(curve: ShiftCurve, secondary_rpm):
    """Predicted engine rpm at given secondary rpm (linear along the curve)."""
    a = curve.arrays()
    order = np.argsort(a["secondary_rpm"])
    return np.interp(np.asarray(secondary_rpm, dtype=float), a["secondary_rpm"][order], a["engine_rpm"][order])


def compare_to_measured(curve: ShiftCurve, measured: list[dict]) -> dict[str, Any]:
    """Engine-rpm residuals (measured - predicted) at the measured secondary rpm."""
    s = np.array([m["secondary_rpm"] for m in measured], dtype=float)
    e = np.array([m["engine_rpm"] for m in measured], dtype=float)
    res = e - predicted_engine_rpm_at(curve, s)
    return {"n": int(res.size), "residual_rpm": res.tolist(), "mean_rpm": float(res.mean()),
            "rms_rpm": float(np.sqrt(np.mean(res ** 2))), "max_abs_rpm": float(np.abs(res).max())}
