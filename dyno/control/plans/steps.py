"""Mode ``steps``: a plan file's ``[[step]]`` list, run in order (docs/control.md, "Plan files").

Step kinds (keys; every time in s, speeds in rpm, torque in N·m):

* ``contact``: apply at full speed until the secondary drops ``drop_rel`` (the pads reach the rotor).
* ``hold``: hold ``variable`` (``secondary`` | ``engine`` rpm, or ``torque``) at each of ``setpoints``
  (or ``setpoint``, or ``from``/``to``/``count``), and measure a point at each: at least ``min_s``, until
  ``ci95`` or ``max_s`` (defaults: the plan's [test] values); ``tolerance_rel``, ``in_band_s``,
  ``max_approach_s`` say when a setpoint is reached or given up; ``load_raises_speed`` = true where more
  brake raises the held speed (the engine while the CVT back-shifts at heavy load; for the engine, without
  the key, one apply pulse finds out: :func:`probe_load_sign`); ``measure`` = false
  only moves there (no point), e.g. to enter a region before another hold.
* ``ramp``: move the setpoint of ``variable`` (secondary | engine) from ``from`` to ``to`` at ``rate_rpm_s``
  under the hold, a point every ``point_s``, each corrected for I·alpha (:mod:`dyno.analysis.inertia`).
* ``brake``: ``direction`` = "apply" | "release" for ``s``.
* ``identify``: the auto-tune of the hold of ``variable`` (``secondary``, default, | ``engine`` rpm) at
  ``setpoint`` (:mod:`dyno.control.plans.autotune`): ``pulse_s``, ``repeats``, ``apply`` (use the identified
  ``kp`` for the rest of the run; default true), ``load_raises_speed`` (as for ``hold``).
* ``throttle``: ``fraction`` 0..1.
* ``wait``: ``s``.

Limits per step (any kind): ``limit_s`` (the step's whole time), ``limit_min_secondary_rpm``,
``limit_max_secondary_rpm``, ``limit_max_torque_nm``; when one is passed the step ends and
``on_limit`` says what follows: ``"next"`` step (default) or ``"abort"`` (safe state).  The safety
checks of the controller run underneath, unchanged, whatever a plan says.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from dyno.control.api import Hold, PlanContext, State
from dyno.control.hold_law import HoldGains
from dyno.control.holds import gains_for
from dyno.control.outputs import APPLY, RELEASE, STOP

KINDS = {
    "contact": {"drop_rel": (0.001, 0.5)},
    "hold": {"variable": ("secondary", "engine", "torque"), "setpoint": (0.0, 1e5), "setpoints": "list",
             "from": (0.0, 1e5), "to": (0.0, 1e5), "count": (1, 200), "min_s": (0.0, 600.0),
             "ci95": (0.0, 1.0), "max_s": (0.0, 600.0), "tolerance_rel": (0.0, 0.5), "in_band_s": (0.0, 60.0),
             "max_approach_s": (0.0, 600.0), "load_raises_speed": "bool", "measure": "bool"},
    "ramp": {"variable": ("secondary", "engine"), "from": (0.0, 1e5), "to": (0.0, 1e5),
             "rate_rpm_s": (1.0, 1e4), "point_s": (0.2, 60.0)},
    "brake": {"direction": ("apply", "release"), "s": (0.0, 60.0)},
    "identify": {"variable": ("secondary", "engine"), "setpoint": (100.0, 1e5), "pulse_s": (0.05, 1.0),
                 "repeats": (1, 10), "apply": "bool", "load_raises_speed": "bool"},
    "throttle": {"fraction": (0.0, 1.0)},
    "wait": {"s": (0.0, 3600.0)},
}
REQUIRED = {"identify": {"setpoint"}, "ramp": {"to", "rate_rpm_s"}, "brake": {"direction", "s"}, "throttle": {"fraction"}, "wait": {"s"}}
LIMITS = {"limit_s": (0.0, 3600.0), "limit_min_secondary_rpm": (0.0, 1e5), "limit_max_secondary_rpm": (0.0, 1e5),
          "limit_max_torque_nm": (0.0, 1e4), "on_limit": ("next", "abort")}


def validate_steps(raw: list, err) -> tuple:
    """The ``[[step]]`` tables checked (``err(field, expected)`` makes the ConfigError)."""
    steps = []
    for i, st in enumerate(raw):
        where = f"step[{i + 1}]"
        if not isinstance(st, dict):
            raise err(where, "a table")
        kind = st.get("kind")
        if kind not in KINDS:
            raise err(f"{where}.kind", f"one of {', '.join(KINDS)}, got {kind!r}")
        allowed = {**KINDS[kind], **LIMITS}
        for key, value in st.items():
            if key == "kind":
                continue
            if key not in allowed:
                raise err(f"{where}.{key}", f"one of {', '.join(sorted(allowed))} for kind {kind!r}")
            spec = allowed[key]
            if spec == "bool":
                if not isinstance(value, bool):
                    raise err(f"{where}.{key}", f"true or false, got {value!r}")
            elif spec == "list":
                if (not isinstance(value, list) or not value
                        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 for v in value)):
                    raise err(f"{where}.{key}", "a non-empty list of positive numbers")
            elif isinstance(spec[0], str):
                if value not in spec:
                    raise err(f"{where}.{key}", f"one of {', '.join(spec)}, got {value!r}")
            else:
                lo, hi = spec
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                        or not lo <= value <= hi:
                    raise err(f"{where}.{key}", f"a number in {lo:g}..{hi:g}, got {value!r}")
        missing = REQUIRED.get(kind, set()) - set(st)
        if missing:
            raise err(f"{where}.{sorted(missing)[0]}", f"required for kind {kind!r}")
        if kind == "hold" and not ({"setpoint", "setpoints"} & set(st) or {"from", "to", "count"} <= set(st)):
            raise err(f"{where}.setpoint", "setpoint, setpoints, or from + to + count")
        if kind == "hold" and st.get("variable", "secondary") == "torque" and "tolerance_rel" not in st:
            st = {**st, "tolerance_rel": 0.03}  # the torque's firing ripple: a wider band
        steps.append(dict(st))
    return tuple(steps)


@dataclass(frozen=True)
class StepsPlan:
    """Mode ``steps``'s parameters: the plan file's ``[[step]]`` tables, checked (:func:`validate_steps`)."""

    steps: tuple = ()


class _Run:
    """What one run of the steps keeps between steps: the holds' gains (an ``identify`` step's replace the
    rig's for the rest of the run)."""

    def __init__(self, ctx: PlanContext) -> None:
        self.ctx = ctx
        self.gains: dict[str, HoldGains] = {}

    def gains_of(self, variable: str) -> HoldGains:
        return self.gains.get(variable) or gains_for(self.ctx.config.control, variable)


async def run_steps(ctx: PlanContext, sp: StepsPlan) -> None:
    run = _Run(ctx)
    for i, st in enumerate(sp.steps):
        t0 = ctx.now()
        try:
            why = await ctx.bounded(_run_step(run, st), lambda st=st, t0=t0: _limit_passed(ctx, st, ctx.now() - t0))
        finally:
            ctx.brake(STOP)
        if ctx.state in (State.DONE, State.ABORTED):
            return
        if why:
            ctx.log("limit", step=i + 1, kind=st["kind"], reason=why)
            if st.get("on_limit", "next") == "abort":
                ctx.fail("plan_limit", f"step {i + 1} ({st['kind']}): {why}")
                return
    if ctx.state is State.WARMUP:
        ctx.phase(State.STEP, "plan: no step took a point")
    ctx.phase(State.DONE, f"plan {ctx.plan.name or 'steps'}: {len(sp.steps)} steps")


def _limit_passed(ctx: PlanContext, st: dict, elapsed_s: float) -> str | None:
    if "limit_s" in st and elapsed_s > st["limit_s"]:
        return f"step time over {st['limit_s']:g} s"
    if "limit_min_secondary_rpm" in st or "limit_max_secondary_rpm" in st:
        rs = ctx.read.secondary_rpm(0.2)
        if rs < st.get("limit_min_secondary_rpm", -math.inf):
            return f"secondary {rs:.0f} rpm below {st['limit_min_secondary_rpm']:g} rpm"
        if rs > st.get("limit_max_secondary_rpm", math.inf):
            return f"secondary {rs:.0f} rpm above {st['limit_max_secondary_rpm']:g} rpm"
    if "limit_max_torque_nm" in st:
        tq = ctx.read.torque_nm(0.2)
        if tq > st["limit_max_torque_nm"]:
            return f"torque {tq:.1f} N·m above {st['limit_max_torque_nm']:g} N·m"
    return None


async def _run_step(run: _Run, st: dict) -> None:
    ctx = run.ctx
    kind = st["kind"]
    if ctx.state is State.WARMUP or ctx.state is State.MEASURE:
        ctx.phase(State.STEP, f"plan step: {kind}")
    if kind == "wait":
        await ctx.sleep(st["s"])
    elif kind == "throttle":
        ctx.throttle(st["fraction"])
        await ctx.sleep(0.05)
    elif kind == "brake":
        ctx.brake(APPLY if st["direction"] == "apply" else RELEASE)
        try:
            await ctx.sleep(st["s"])
        finally:
            ctx.brake(STOP)
    elif kind == "contact":
        from dyno.control.plans.speed_hold import find_contact

        await find_contact(ctx, st.get("drop_rel", 0.01), st.get("limit_s", 10.0))
    elif kind == "hold":
        await _hold_step(run, st)
    elif kind == "ramp":
        await _ramp_step(run, st)
    elif kind == "identify":
        from dyno.control.plans.autotune import identify_gain

        variable = st.get("variable", "secondary")
        base = run.gains_of(variable)
        result = await identify_gain(ctx, variable, st["setpoint"], base,
                                     load_raises=await load_raises(ctx, st, variable),
                                     pulse_s=st.get("pulse_s", 0.2), repeats=int(st.get("repeats", 2)))
        if result["ok"] and st.get("apply", True):
            run.gains[variable] = replace(base, kp=result["kp_identified"])
            result["applied"] = True
        ctx.log("identify", **result)


async def load_raises(ctx: PlanContext, st: dict, variable: str) -> bool:
    """Whether more brake raises ``variable`` (the hold's usual sense is the other): as the step says
    (``load_raises_speed``), else, for the engine, probed (:func:`probe_load_raises`) — a CVT that
    back-shifts under load raises the engine, one that shifts flat lowers it."""
    if "load_raises_speed" in st:
        return bool(st["load_raises_speed"])
    return await probe_load_raises(ctx, variable) if variable == "engine" else False


async def probe_load_raises(ctx: PlanContext, variable: str, pulse_s: float = 0.4, watch_s: float = 1.5) -> bool:
    """One apply pulse, and which way ``variable`` went: True when it rose (logged ``probe``)."""
    before = ctx.read.value(variable, 0.5)
    ctx.brake(APPLY)
    try:
        await ctx.sleep(pulse_s)
    finally:
        ctx.brake(STOP)
    await ctx.sleep(watch_s)
    after = ctx.read.value(variable, 0.5)
    raises = after > before
    ctx.log("probe", variable=variable, before=before, after=after, pulse_s=pulse_s, load_raises_speed=raises)
    return raises


def _setpoints(st: dict) -> list[float]:
    if "setpoints" in st:
        return [float(v) for v in st["setpoints"]]
    if "setpoint" in st:
        return [float(st["setpoint"])]
    n = int(st["count"])
    a, b = float(st["from"]), float(st["to"])
    return [a + (b - a) * i / max(1, n - 1) for i in range(n)]


#: each hold variable's figure in a point
POINT_FIELD = {"secondary": "rpm_secondary", "engine": "rpm_primary", "torque": "torque_secondary_nm"}


async def _hold_step(run: _Run, st: dict) -> None:
    """Hold each setpoint, measure a point with the brake frozen there (as the speed-hold plan does)."""
    ctx = run.ctx
    variable = st.get("variable", "secondary")
    raises = await load_raises(ctx, st, variable)
    tol = st.get("tolerance_rel", 0.0075)
    band = max(0.02, 2 * tol)  # a window's mean, or a timed-out hold, this far off is no point
    p = ctx.plan
    measure_plan = replace(p, measure_s=st.get("min_s", p.measure_s), max_measure_s=st.get("max_s", p.max_measure_s),
                           target_efficiency_ci95=st.get("ci95", p.target_efficiency_ci95 or 0.01))
    for sp in _setpoints(st):
        if ctx.state is not State.STEP:
            ctx.phase(State.STEP, f"hold {variable} at {sp:g}")
        ctx.phase(State.SETTLE, f"holding {variable} at {sp:g} until within {tol:.1%}")
        held = await ctx.hold(Hold(variable, sp, tolerance_rel=tol, in_band_s=st.get("in_band_s", 0.8),
                                   max_approach_s=st.get("max_approach_s", 8.0), load_raises=raises,
                                   gains=run.gains_of(variable)))
        if not held.reached:
            # judged as the measurement's give-up judges it (0.5 s of data, its band), not by the hold's
            # short window alone: a torque's 0.2 s mean scatters by several % about a steady hold
            x = ctx.read.value(variable, 0.5)
            if not abs(x - sp) <= band * sp:
                ctx.log("skip", reason=f"cannot hold {variable} at {sp:g} (at {x:.1f} after {held.settle_s:.1f} s)")
                continue
        if not st.get("measure", True):  # a "go to" hold: reach the setpoint, take no point
            continue
        point, h0, h1 = await ctx.measure(
            give_up=lambda: not abs(ctx.read.value(variable, 0.5) - sp) <= band * sp, plan=measure_plan)
        point.update(settled_by="held" if held.reached else "timeout", settle_s=held.settle_s, setpoint=sp,
                     hold_variable=variable)
        mean = point[POINT_FIELD[variable]]
        if point.get("gave_up") or not abs(mean - sp) <= band * sp:  # shifted under the brake
            ctx.log("skip", reason=f"{variable} drifted to {mean:.1f} while measuring at {sp:g}: not steady")
            continue
        ctx.record(point, h0, h1)


async def _ramp_step(run: _Run, st: dict) -> None:
    """Move the held setpoint at ``rate_rpm_s``; a point (I·α corrected) every ``point_s``."""
    ctx = run.ctx
    variable = st.get("variable", "secondary")
    a = float(st.get("from", ctx.read.value(variable, 0.3)))
    b = float(st["to"])
    rate = float(st["rate_rpm_s"])
    point_s = float(st.get("point_s", 1.0))
    gains = run.gains_of(variable)
    if ctx.state is not State.STEP:
        ctx.phase(State.STEP, f"ramp {variable} {a:.0f} -> {b:.0f} rpm at {rate:g} rpm/s")
    ctx.phase(State.SETTLE, f"ramp: reaching {a:.0f} rpm")
    await ctx.hold(Hold(variable, a, tolerance_rel=0.01, in_band_s=0.0, max_approach_s=8.0, gains=gains))
    await ctx.loaded(wait_warm_up=True)
    ctx.phase(State.MEASURE, f"ramp {variable} {a:.0f} -> {b:.0f} rpm")
    t_start = ctx.now()
    duration = abs(b - a) / rate
    await ctx.hold(Hold(variable, b, gains=gains, rate_per_s=rate, wait=False))
    while ctx.now() - t_start < duration - 1e-9:
        window_s = min(point_s, t_start + duration - ctx.now())
        if window_s < 0.5 * point_s:
            break  # (a sliver at the ramp's end is no point: too few revolutions for its I·α)
        point, h0, h1 = await ctx.measure(fixed_s=window_s)
        point = ctx.read.inertia_corrected(point)
        setpoint = a + math.copysign(rate, b - a) * min(duration, ctx.now() - t_start)
        point.update(settled_by="ramp", settle_s=0.0, setpoint=setpoint, hold_variable=variable,
                     ramp_rate_rpm_s=math.copysign(rate, b - a))
        ctx.record(point, h0, h1)
