"""Slip-consistent inverse: from a measured speed ratio to the geometric ratio and the belt's slip.

A dyno measures the *speed* ratio ``n_p / n_s``; the belt model takes the
*geometric* ratio ``i = r_s / r_p`` and the clamping force, and predicts the
belt's speed efficiency ``eta_v``.  They are tied by the slip ``s = 1 - eta_v``::

    n_p / n_s = i / (1 - s(i, T_p, F_p(i)))

with ``F_p(i)`` the clamping force the tune puts on the belt at that ratio and
engine speed (flyweights minus spring, Messick eq. 9.3: :func:`clamp_from_tune`).
:func:`invert_speed_ratio` solves this for ``i`` by fixed-point iteration
``i <- SR (1 - s(i))``: the slip changes little with the ratio (|ds/di| ~ 1e-2
on the Table 6.1 belt), so each step gains about two digits and 3-5 slip
evaluations reach 1e-8.

The slip comes from a *tier* (a function of an :class:`OperatingPoint`):

* :func:`slip_table`: the full model tabulated over ratio x torque at the
  tune's clamp (``dyno.sim.belt_table.BeltTable``), microseconds per call;
* :func:`slip_closed_form`: Sorge & Cammalleri's closed form: Reynolds creep
  only, 3-10x below the full model's slip (an order of 0.1 % against 0.3-2 %);
* :func:`slip_full`: the thesis BVP itself, warm-started from the previous
  call (0.2-1 s per call: seconds per point; too slow for a live overlay).

Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Callable

from dyno.errors import MODEL_FAILURES, ConfigError
from dyno.model.params import ModelParams, OperatingPoint

STATES = ("steady", "gross_slip", "no_clamp", "failed")


@dataclass(frozen=True)
class InverseResult:
    """Geometric ratio and slip that reproduce one measured point (``state == "steady"``)."""

    speed_ratio: float            # measured n_p / n_s
    primary_speed_rpm: float
    primary_torque_nm: float
    geometric_ratio: float        # r_s / r_p; NaN unless steady
    slip: float                   # 1 - eta_speed of the belt; NaN unless steady
    primary_axial_force_n: float  # clamp at the geometric ratio (NaN with a fixed slack tension)
    tier: str
    state: str
    reason: str = ""
    iterations: int = 0
    slack_tension_n: float | None = None

    @property
    def ok(self) -> bool:
        return self.state == "steady"

    def operating_point(self) -> OperatingPoint:
        """The point the belt model should predict at (geometric ratio, the tune's clamp)."""
        if not self.ok:
            raise ValueError(f"no operating point: {self.state} ({self.reason})")
        if self.slack_tension_n is not None:
            return OperatingPoint(ratio=self.geometric_ratio, primary_speed_rpm=self.primary_speed_rpm,
                                  primary_torque_nm=self.primary_torque_nm, slack_tension_n=self.slack_tension_n)
        return OperatingPoint(ratio=self.geometric_ratio, primary_speed_rpm=self.primary_speed_rpm,
                              primary_torque_nm=self.primary_torque_nm, slack_tension_n=None,
                              primary_axial_force_n=self.primary_axial_force_n)

    def as_dict(self) -> dict:
        return asdict(self)


SlipFn = Callable[[OperatingPoint], float]


def clamp_from_tune(tune, primary_speed_rpm: float) -> Callable[[float], float]:
    """``ratio -> primary clamping force (N)`` of a CVT tune at an engine speed.

    Flyweights (or rollers) minus spring (Messick eq. 9.3) at the primary pitch
    radius the belt length gives for the ratio on the tune's drive.  Negative
    below engagement (the spring holds the sheave open).
    """
    from dyno.model.geometry import radii_for_ratio
    from dyno.tuning.actuators import primary_axial_force_n

    d = tune.drive
    rpm = float(primary_speed_rpm)

    def clamp(ratio: float) -> float:
        r_p, _ = radii_for_ratio(float(ratio), d.belt_pitch_length_m, d.centre_distance_m)
        return float(primary_axial_force_n(tune, rpm, r_p))

    return clamp


def slip_closed_form(params: ModelParams) -> SlipFn:
    """Reynolds creep of the closed form (an order of magnitude below the full model's slip)."""
    from dyno.model.closed_form import closed_form_point

    def slip(op: OperatingPoint) -> float:
        return 1.0 - closed_form_point(params, op).efficiency_speed

    slip.tier = "closed_form"
    return slip


def slip_table(table) -> SlipFn:
    """Slip from a belt-model table (``lookup(ratio, torque) -> (eta_torque, eta_speed)`` or None).

    The table fixes its own clamp (the tune's at the table's engine speed), so
    only the ratio and the torque of the point are used.
    """

    def slip(op: OperatingPoint) -> float:
        v = table.lookup(op.ratio, op.primary_torque_nm)
        if v is None:
            reason = _table_reason(table, op)
            raise _NoAnswer(reason)
        return 1.0 - v[1]

    slip.tier = "table"
    return slip


def slip_full(params: ModelParams, *, variant: str = "corrected", slip_threshold_m_s: float = 1e-4,
              tol: float = 1e-3, time_limit_s: float = 30.0) -> SlipFn:
    """Slip of the full model, each solve warm-started from the previous one (seconds per point)."""
    state = {"guess": None}

    def slip(op: OperatingPoint) -> float:
        from dyno.model.solution import solve_point

        sol = solve_point(params, op, variant=variant, slip_threshold_m_s=slip_threshold_m_s, tol=tol,
                          guess=state["guess"], time_limit_s=time_limit_s)
        state["guess"] = sol
        return 1.0 - float(sol.summary["efficiency"]["speed"])

    slip.tier = "full"
    slip.state = state  # the warm start: invert_points points it at a neighbour to retry a failed point
    return slip


class _NoAnswer(Exception):
    """The slip tier has no answer at this point (a failed table cell)."""


def _table_reason(table, op) -> str:
    errors = getattr(table, "errors", {}) or {}
    if errors:
        near = min(errors, key=lambda k: abs(k[0] - op.ratio) + abs(k[1] - op.primary_torque_nm) / 10.0)
        return f"belt table has no answer near ratio {op.ratio:.3f}, {op.primary_torque_nm:.1f} N*m: {errors[near]}"
    return f"belt table has no answer at ratio {op.ratio:.3f}, {op.primary_torque_nm:.1f} N*m"


def invert_speed_ratio(speed_ratio: float, primary_speed_rpm: float, primary_torque_nm: float, *,
                       slip: SlipFn, clamp: Callable[[float], float] | float | None = None,
                       slack_tension_n: float | None = None, ratio_range: tuple[float, float] | None = None,
                       tol: float = 1e-9, max_iter: int = 30) -> InverseResult:
    """Geometric ratio ``i`` and slip ``s`` with ``i / (1 - s(i)) == speed_ratio``.

    ``clamp(ratio) -> N`` (e.g. :func:`clamp_from_tune`) or a fixed clamp, or
    ``slack_tension_n`` (no tune: the thesis's fixed slack-span tension).  ``ratio_range``
    keeps the iteration inside the drive's geometric range.  Never raises for a
    physical reason: the result's ``state`` says ``gross_slip`` (the tier finds no
    steady belt at this load and clamp), ``no_clamp`` (the spring holds the
    sheave open) or ``failed`` (with the numerical reason).
    """
    sr, rpm, torque = float(speed_ratio), float(primary_speed_rpm), float(primary_torque_nm)
    tier = getattr(slip, "tier", "custom")
    base = dict(speed_ratio=sr, primary_speed_rpm=rpm, primary_torque_nm=torque, tier=tier,
                slack_tension_n=slack_tension_n)

    def failed(state, reason, i=math.nan, f=math.nan, it=0):
        return InverseResult(geometric_ratio=math.nan, slip=math.nan, primary_axial_force_n=f, state=state,
                             reason=reason, iterations=it, **base)

    if not (math.isfinite(sr) and sr > 0 and math.isfinite(rpm) and rpm > 0 and math.isfinite(torque)):
        return failed("failed", f"speed ratio, rpm and torque must be finite and positive, got {sr}, {rpm}, {torque}")
    if (clamp is None) == (slack_tension_n is None):
        raise ValueError("give exactly one of clamp and slack_tension_n")
    lo, hi = ratio_range if ratio_range is not None else (0.0, math.inf)

    def op_at(i: float) -> tuple[OperatingPoint, float]:
        if slack_tension_n is not None:
            return OperatingPoint(ratio=i, primary_speed_rpm=rpm, primary_torque_nm=max(torque, 0.0),
                                  slack_tension_n=slack_tension_n), math.nan
        f = float(clamp(i)) if callable(clamp) else float(clamp)
        if not f > 0.0:
            return None, f
        return OperatingPoint(ratio=i, primary_speed_rpm=rpm, primary_torque_nm=max(torque, 0.0),
                              slack_tension_n=None, primary_axial_force_n=f), f

    i = min(max(sr, lo), hi)
    f = math.nan
    for it in range(1, max_iter + 1):
        op, f = op_at(i)
        if op is None:
            return failed("no_clamp", f"the tune's clamp at ratio {i:.3f}, {rpm:.0f} rpm is {f:.0f} N: "
                          "the spring holds the primary open", i, f, it)
        try:
            s = float(slip(op))
        except _NoAnswer as exc:
            return failed("gross_slip" if "gross slip" in str(exc) else "failed", str(exc), i, f, it)
        except MODEL_FAILURES as exc:
            state = "gross_slip" if type(exc).__name__ == "GrossSlip" else "failed"
            return failed(state, str(exc), i, f, it)
        except ConfigError as exc:
            return failed("failed", str(exc), i, f, it)
        i_new = min(max(sr * (1.0 - s), lo), hi)
        if abs(i_new - i) <= tol * i:
            op, f = op_at(i_new)
            return InverseResult(geometric_ratio=i_new, slip=1.0 - i_new / sr, primary_axial_force_n=f,
                                 state="steady", reason="", iterations=it, **base)
        i = i_new
    return failed("failed", f"fixed point did not settle in {max_iter} slip evaluations (last ratio {i:.6f})",
                  i, f, max_iter)


RAD_S_PER_RPM = math.pi / 30.0
INVERSE_TIERS = ("closed_form", "full")


def invertible(point: dict) -> bool:
    """A point the inverse can take: finite positive speeds and speed ratio, and an input power."""
    rp, rs, sr, p_in = (point.get(k) for k in ("rpm_primary", "rpm_secondary", "ratio", "power_in_w"))
    if any(v is None or isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
           for v in (rp, rs, sr, p_in)):
        return False
    return rp > 0 and rs > 0 and sr > 0


def invert_points(points, tune=None, *, tier: str = "closed_form", params: ModelParams | None = None,
                  slack_tension_n: float = 100.0) -> list[tuple[float, InverseResult]]:
    """``(secondary rpm, InverseResult)`` of each measured point with a speed ratio and an input power.

    ``points``: reduced points (dicts with ``rpm_primary``, ``rpm_secondary``,
    ``ratio`` = n_p/n_s, ``power_in_w``).  The primary torque is the one the
    measured efficiency used (``power_in_w / omega_p``, the engine map's).  With
    ``tune`` the clamp is the tune's at each point's measured engine speed and
    the belt model runs on the tune's drive; without, ``slack_tension_n`` on
    Table 6.1.  ``tier`` is the slip's: ``closed_form`` (microseconds per point)
    or ``full`` (the BVP, warm-started point to point: seconds per point).
    """
    from dyno.model.params import TABLE_6_1, bad_input

    if tier not in INVERSE_TIERS:
        raise bad_input("tier", f"one of {', '.join(INVERSE_TIERS)}, got {tier!r}")
    if params is None:
        if tune is not None:
            from dyno.tuning.tune import model_params_for

            params = model_params_for(tune)
        else:
            params = TABLE_6_1
    slip = slip_closed_form(params) if tier == "closed_form" else slip_full(params)
    ratio_range = None
    if tune is not None:
        from dyno.model.geometry import secondary_radius_m

        d = tune.drive
        ratio_range = tuple(sorted(secondary_radius_m(r, d.belt_pitch_length_m, d.centre_distance_m) / r
                                   for r in (d.primary_radius_max_m, d.primary_radius_min_m)))
    def invert(p) -> InverseResult:
        rp, sr, p_in = (p.get(k) for k in ("rpm_primary", "ratio", "power_in_w"))
        torque = float(p_in) / (float(rp) * RAD_S_PER_RPM)
        if tune is not None:
            return invert_speed_ratio(sr, rp, torque, slip=slip, clamp=clamp_from_tune(tune, rp),
                                      ratio_range=ratio_range)
        return invert_speed_ratio(sr, rp, torque, slip=slip, slack_tension_n=slack_tension_n)

    usable = [p for p in points if invertible(p)]
    out, solved = [], {}  # solved: index -> the full tier's last solution there (a retry's warm start)
    for k, p in enumerate(usable):
        res = invert(p)
        out.append((float(p["rpm_secondary"]), res))
        if tier == "full" and res.ok:
            solved[k] = slip.state["guess"]
    if tier == "full" and solved:
        # Each solve starts from the previous point's solution; the first point (or one after a failure)
        # starts from nothing, which at a heavy clamp can fail where a start from its run's next solved
        # point converges: retry those once from the nearest solved point.  Gross slip and no clamp are
        # the physics' answers, not retried.
        for k, (rs, res) in enumerate(out):
            if res.state == "failed":
                slip.state["guess"] = solved[min(solved, key=lambda j: abs(j - k))]
                out[k] = (rs, invert(usable[k]))
    return out
