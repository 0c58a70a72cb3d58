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

import asyncio
import math

from dyno.control.api import State
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


class LimitReached(Exception):
    pass


async def run_steps(ctx) -> None:
    for i, st in enumerate(ctx.plan.steps):
        task = ctx.hold_task(_run_step(ctx, st), name=f"step-{i + 1}")
        why = None
        t0 = ctx.now()
        try:
            while not task.done():
                await asyncio.wait({task}, timeout=0.05)
                why = None if task.done() else _limit_passed(ctx, st, ctx.now() - t0)
                if why:
                    task.cancel()
                    await asyncio.gather(task, return_exceptions=True)
                    break
            if not why:
                task.result()
        finally:
            if not task.done():
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
            ctx.brake(STOP)
        if ctx.state in (State.DONE, State.ABORTED):
            return
        if why:
            ctx.log("limit", step=i + 1, kind=st["kind"], reason=why)
            if st.get("on_limit", "next") == "abort":
                ctx.fail("plan_limit", f"step {i + 1} ({st['kind']}): {why}")
                return
    if ctx.state is not State.DONE:
        if ctx.state is State.WARMUP:
            ctx.phase(State.STEP, "plan: no step took a point")
        ctx.phase(State.DONE, f"plan {ctx.plan.name or 'steps'}: {len(ctx.plan.steps)} steps")


def _limit_passed(ctx, st: dict, elapsed_s: float) -> str | None:
    from dyno.control.plans.speed_hold import brake_torque_nm, secondary_rpm

    if "limit_s" in st and elapsed_s > st["limit_s"]:
        return f"step time over {st['limit_s']:g} s"
    if "limit_min_secondary_rpm" in st or "limit_max_secondary_rpm" in st:
        rs = secondary_rpm(ctx, 0.2)
        if rs < st.get("limit_min_secondary_rpm", -math.inf):
            return f"secondary {rs:.0f} rpm below {st['limit_min_secondary_rpm']:g} rpm"
        if rs > st.get("limit_max_secondary_rpm", math.inf):
            return f"secondary {rs:.0f} rpm above {st['limit_max_secondary_rpm']:g} rpm"
    if "limit_max_torque_nm" in st:
        tq = brake_torque_nm(ctx, 0.2)
        if tq > st["limit_max_torque_nm"]:
            return f"torque {tq:.1f} N·m above {st['limit_max_torque_nm']:g} N·m"
    return None


async def _run_step(ctx, st: dict) -> None:
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
        await find_contact(ctx, st.get("drop_rel", 0.01), st.get("limit_s", 10.0))
    elif kind == "hold":
        await _hold_step(ctx, st)
    elif kind == "ramp":
        await _ramp_step(ctx, st)
    elif kind == "identify":
        from dyno.control.plans.autotune import identify_gain

        variable = st.get("variable", "secondary")
        await identify_gain(ctx, variable, st["setpoint"],
                            sign=await load_sign(ctx, st, variable), pulse_s=st.get("pulse_s", 0.2),
                            repeats=int(st.get("repeats", 2)), apply=st.get("apply", True))


async def load_sign(ctx, st: dict, variable: str) -> float:
    """+1 where more brake lowers ``variable`` (the hold's usual sense), -1 where it raises it: as the step
    says (``load_raises_speed``), else, for the engine, probed (:func:`probe_load_sign`) — a CVT that
    back-shifts under load raises the engine, one that shifts flat (the stock CVT on the 2019 logs) lowers it."""
    if "load_raises_speed" in st:
        return -1.0 if st["load_raises_speed"] else 1.0
    return await probe_load_sign(ctx, variable) if variable == "engine" else 1.0


async def probe_load_sign(ctx, variable: str, pulse_s: float = 0.4, watch_s: float = 1.5) -> float:
    """One apply pulse, and which way ``variable`` went: +1 down (more brake lowers it), -1 up (logged ``probe``)."""
    from dyno.control.plans.speed_hold import measured

    before = measured(ctx, variable, 0.5)
    ctx.brake(APPLY)
    try:
        await ctx.sleep(pulse_s)
    finally:
        ctx.brake(STOP)
    await ctx.sleep(watch_s)
    after = measured(ctx, variable, 0.5)
    sign = -1.0 if after > before else 1.0
    ctx.log("probe", variable=variable, before=before, after=after, pulse_s=pulse_s, load_raises_speed=sign < 0)
    return sign


async def find_contact(ctx, drop_rel: float = 0.01, timeout_s: float = 10.0) -> bool:
    """Full-speed apply until the secondary drops ``drop_rel`` below its speed now (the pads bite)."""
    from dyno.control.plans.speed_hold import secondary_rpm

    no_load = secondary_rpm(ctx, 1.0)
    t_c = ctx.now()
    ctx.brake(APPLY)
    try:
        while secondary_rpm(ctx, 0.15) > no_load * (1.0 - drop_rel):
            if ctx.now() - t_c > timeout_s:
                ctx.fail("error", f"the brake did not slow the secondary in {timeout_s:g} s")
                return False
            await ctx.sleep(0.02)
    finally:
        ctx.brake(STOP)
    ctx.log("contact", after_s=ctx.now() - t_c)
    ctx.mark_loaded()  # the CVT is loaded from here (warm-up criterion)
    return True


def _setpoints(st: dict) -> list[float]:
    if "setpoints" in st:
        return [float(v) for v in st["setpoints"]]
    if "setpoint" in st:
        return [float(st["setpoint"])]
    n = int(st["count"])
    a, b = float(st["from"]), float(st["to"])
    return [a + (b - a) * i / max(1, n - 1) for i in range(n)]


async def _hold_step(ctx, st: dict) -> None:
    """Hold each setpoint, measure a point with the brake frozen there (as the speed-hold plan does)."""
    from dataclasses import replace

    from dyno.control.plans.speed_hold import SpeedHold, _hold_loop, gains_for, measured

    variable = st.get("variable", "secondary")
    gains = gains_for(ctx, variable)
    hold = SpeedHold(gains)
    sps = _setpoints(st)
    target = {"rpm": sps[0]}
    if await load_sign(ctx, st, variable) < 0:
        target["sign"] = -1.0
    tol = st.get("tolerance_rel", 0.0075)
    p = ctx.plan
    measure_plan = replace(p, measure_s=st.get("min_s", p.measure_s), max_measure_s=st.get("max_s", p.max_measure_s),
                           target_efficiency_ci95=st.get("ci95", p.target_efficiency_ci95 or 0.01))
    task = ctx.hold_task(_hold_loop(ctx, hold, target, variable), name=f"hold-{variable}")
    try:
        for sp in sps:
            target["rpm"] = sp
            if ctx.state is not State.STEP:
                ctx.phase(State.STEP, f"hold {variable} at {sp:g}")
            ctx.phase(State.SETTLE, f"holding {variable} at {sp:g} until within {tol:.1%}")
            t0, since, by = ctx.now(), None, "held"
            while True:
                await ctx.sleep(0.05)
                if task.done():
                    task.result()
                x = measured(ctx, variable, gains.speed_window_s)
                if abs(x - sp) <= tol * sp:
                    since = since if since is not None else ctx.now()
                    if ctx.now() - since >= st.get("in_band_s", 0.8):
                        break
                else:
                    since = None
                if ctx.now() - t0 > st.get("max_approach_s", 8.0):
                    by = "timeout"
                    break
            if by == "timeout":
                # judged as the measurement's give-up judges it (0.5 s of data, its band), not by the last
                # short window alone: a torque's 0.2 s mean scatters by several % about a steady hold
                x = measured(ctx, variable, 0.5)
            if by == "timeout" and not abs(x - sp) <= max(0.02, 2 * tol) * sp:
                ctx.log("skip", reason=f"cannot hold {variable} at {sp:g} (at {x:.1f} after "
                                         f"{ctx.now() - t0:.1f} s)")
                continue
            settle_s = ctx.now() - t0
            if not st.get("measure", True):  # a "go to" hold: reach the setpoint, take no point
                continue
            target["frozen"] = True
            try:
                point, h0, h1 = await ctx.measure(give_up=lambda: not abs(
                    measured(ctx, variable, 0.5) - sp) <= max(0.02, 2 * tol) * sp, plan=measure_plan)
            finally:
                target["frozen"] = False
            point.update(settled_by=by, settle_s=settle_s, setpoint=sp, hold_variable=variable)
            mean = point[{"secondary": "rpm_secondary", "engine": "rpm_primary", "torque": "torque_secondary_nm"}[variable]]
            if point.get("gave_up") or not abs(mean - sp) <= max(0.02, 2 * tol) * sp:  # shifted under the brake
                ctx.log("skip", reason=f"{variable} drifted to {mean:.1f} while measuring at {sp:g}: not steady")
                continue
            ctx.record(point, h0, h1)
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        ctx.brake(STOP)


async def _ramp_step(ctx, st: dict) -> None:
    """Move the held setpoint at ``rate_rpm_s``; a point (I·alpha corrected) every ``point_s``."""
    from dyno.analysis.inertia import correct_inertia
    from dyno.analysis.points import reduce_point
    from dyno.control.plans.speed_hold import SpeedHold, _hold_loop, gains_for, measured

    variable = st.get("variable", "secondary")
    gains = gains_for(ctx, variable)
    hold = SpeedHold(gains)
    a = float(st.get("from", measured(ctx, variable, 0.3)))
    b = float(st["to"])
    rate = float(st["rate_rpm_s"]) * (1.0 if b >= a else -1.0)
    point_s = float(st.get("point_s", 1.0))
    from dyno.rig.config import InertiaConfig

    inertia = ctx.config.inertia or InertiaConfig()  # rig.toml [inertia]: the one source
    j_e, j_s = inertia.engine_kg_m2, inertia.secondary_kg_m2
    target = {"rpm": a}
    task = ctx.hold_task(_hold_loop(ctx, hold, target, variable), name=f"ramp-{variable}")
    try:
        if ctx.state is not State.STEP:
            ctx.phase(State.STEP, f"ramp {variable} {a:.0f} -> {b:.0f} rpm at {abs(rate):g} rpm/s")
        ctx.phase(State.SETTLE, f"ramp: reaching {a:.0f} rpm")
        t0 = ctx.now()
        while abs(measured(ctx, variable, gains.speed_window_s) - a) > 0.01 * a and ctx.now() - t0 < 8.0:
            await ctx.sleep(0.05)
        await ctx.warm_up_at_load()
        ctx.phase(State.MEASURE, f"ramp {variable} {a:.0f} -> {b:.0f} rpm")
        t_start = ctx.now()
        duration = abs(b - a) / abs(rate)
        while ctx.now() - t_start < duration - 1e-9:
            h0, d0, r0 = ctx.host_now(), ctx.device_now_us(), ctx.now()
            t_end = min(r0 + point_s, t_start + duration)
            while ctx.now() < t_end - 1e-9:
                await ctx.sleep(0.05)
                if task.done():
                    task.result()
                target["rpm"] = a + rate * (ctx.now() - t_start)
            h1, d1 = ctx.host_now(), ctx.device_now_us()
            point = reduce_point(ctx.streams, d0, d1, ctx.config.calibration, ctx.config.engine_map,
                                 index=len(ctx.points), throttle_frac=ctx.throttle_frac)
            point = correct_inertia(point, ctx.streams, ctx.config.engine_map, j_e, j_s)
            point.update(settled_by="ramp", settle_s=0.0, setpoint=target["rpm"], hold_variable=variable,
                         ramp_rate_rpm_s=rate)
            ctx.record(point, h0, h1)
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        ctx.brake(STOP)
