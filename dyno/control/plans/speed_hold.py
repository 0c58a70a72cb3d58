"""Closed-loop speed hold on the brake actuator, and the steady test built on it.

The plant seen from the controller: a linear actuator that *integrates* its command
(it moves at a fixed speed while powered, through a direction relay and an enable),
pushing a friction brake whose torque slows the CVT's secondary.  So the command is
the actuator's velocity, in [-1, 1] of full speed, and a proportional law on the
speed error is already integral action on the brake position::

    e(t) = (n_s - n_set) / n_set                     (> 0: too fast, more brake)
    u(t) = K_p e(t) + K_i ∫ e dt                     clipped to [-1, 1]

``u`` becomes one actuator pulse per control period ``T``: APPLY (u > 0) or RELEASE
for ``|u| T`` seconds, nothing inside the dead band or below the minimum pulse.  The
relay's settle and dead time are the actuator driver's business (the real one,
:class:`dyno.hw.outputs.GpioActuators`, holds the enable off while the relay moves),
so short pulses cost more than their length: that is why ``min_pulse_s`` exists.
Anti-windup: the integral is frozen while ``u`` is saturated in the error's
direction.  The safety checks are unchanged: they run on every poll, whatever this
loop is doing, and an abort cancels it.

Speed is the mean over the last ``speed_window_s`` by edge count (immune to the
firing ripple that makes single periods scatter).
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass

from dyno.acquisition.rpm import rpm_by_count
from dyno.control.api import State
from dyno.control.outputs import APPLY, RELEASE, STOP
from dyno.protocol import v1


@dataclass(frozen=True)
class SpeedHoldGains:
    """Tuned on the simulated rig (bench/bench_test_time.py's step part), whose actuator, relay and CVT
    keep the real ones' limits.  The law, on the actuator's velocity ``u`` (the actuator
    integrates it into the brake's position)::

        u = kp · (e + lead_s · de/dt)

    The ``kp`` part moves the brake while the error lasts (it holds a constant load with zero
    error: no ``ki`` needed); the ``lead_s`` part sets the brake's position in proportion to
    the error (a PI on position), which damps a plant whose speed answers the brake slowly.
    On the logs' plant (a CVT that shifts at a flat engine speed) a brake pulse near 3,000 rpm
    shows in the secondary's speed ~0.5 s later (a 0.2 s pulse moves it ~7 %, g ≈ 0.38 /s; a
    50 ms one only ~0.3 %: the relay eats the first ~30 ms): the former pure ``kp`` = 3 (tuned
    on the former plant) took 3.4-8 s and rang 1-2 %, higher kp oscillated; ``kp`` 12 with a 0.5 s lead settles 5 % steps within ±0.5 % in ≤ 1.5 s
    (seeds 1-10).  The dead band is judged on the error one lead ahead (where it is heading),
    so a correction already under way is not doubled while the plant's lag hides it.

    Near the setpoint, once a pulse has gone against the one before it (the last correction crossed the whole
    dead band), the minimum pulse is ``fine_pulse_s`` (10 ms) until the error leaves ``fine_band_rel``.
    The CVT's shift has Coulomb friction (:mod:`dyno.sim.cvt_friction`, bounded by the 2019 logs): once the
    error is small the sheaves stick inside the dead band, the ratio is fixed, and the secondary answers the
    brake with the engine's own slope alone: one 20 ms pulse (0.10-0.14 mm of actuator) then moved it 0.8-1 %,
    wider than the +-0.5 % band, so the hold limit-cycled one pulse each way (sd 0.31-0.35 % on 5 % steps,
    settling 3-8 s; docs/measurements/2026-11-29-hold-friction.md).  A 10 ms pulse (~0.06 mm) halves the step:
    sd <= 0.22 % over seeds 1-10 and the friction's whole range.  A reversal shorter than the relay's settle still
    moves nothing (the driver's sequence), as before.  Only after a reversal: a plant that the coarse pulse does
    not overshoot keeps it (fewer pulses; a plant stepped coarser than 10 ms cannot resolve the fine one)."""

    kp: float = 12.0  # actuator speed fraction per unit relative speed error
    ki_per_s: float = 0.0
    period_s: float = 0.05  # one pulse decision per period
    deadband_rel: float = 0.004  # |e| below this: no pulse (relay wear, hunting)
    min_pulse_s: float = 0.02
    speed_window_s: float = 0.15
    ff_s: float = 0.0  # feed-forward: full-speed travel (s) per unit relative setpoint change
    lead_s: float = 0.5  # the position term's lead (the plant's lag); 0: the actuator's speed alone
    derivative_window_s: float = 0.1  # the error's rate over this span (two periods)
    # Near the setpoint after a reversal the minimum pulse is shorter (the CVT's stuck sheaves, above); 0: off
    fine_pulse_s: float = 0.01
    fine_band_rel: float = 0.01  # "near": |error one lead ahead| below this

    @classmethod
    def from_config(cls, control, variable: str = "secondary") -> "SpeedHoldGains":
        """The gains ``rig.toml``'s ``[control]`` gives for ``variable`` (secondary | engine | torque)."""
        kp = {"secondary": control.kp_speed, "engine": control.kp_engine, "torque": control.kp_torque}[variable]
        lead = {"secondary": control.lead_speed_s, "engine": control.lead_engine_s, "torque": 0.0}[variable]
        return cls(kp=kp, period_s=control.period_s, deadband_rel=control.deadband_rel,
                   min_pulse_s=control.min_pulse_s, ff_s=control.ff_speed_s if variable == "secondary" else 0.0,
                   speed_window_s=0.2 if variable == "torque" else cls.speed_window_s, lead_s=lead)


class SpeedHold:
    """The law above (pure: no I/O, time passed in)."""

    def __init__(self, gains: SpeedHoldGains = SpeedHoldGains()) -> None:
        self.g = gains
        self.reset()

    def reset(self) -> None:
        self.integral = 0.0
        self.owed_s = 0.0  # actuator travel asked for but not yet given (s at full speed)
        self.e_hist: list[float] = []  # the last errors, one a period (the rate over derivative_window_s)
        self.e_lead = math.nan  # e + lead·de/dt: where the error is heading
        self.last_dir = 0  # the last pulse's direction (+1 apply, -1 release, 0 none yet)
        self.fine = False  # near the setpoint after a reversal there: the minimum pulse is ``fine_pulse_s``

    def update(self, rpm: float, setpoint_rpm: float, dt_s: float) -> float:
        """Actuator command in [-1, 1] (+: apply more brake) for the measured ``rpm``."""
        if not (rpm > 0 and setpoint_rpm > 0):
            return 0.0
        return self.command((rpm - setpoint_rpm) / setpoint_rpm, dt_s)

    def feed_forward(self, old_setpoint: float, new_setpoint: float, sign: float = -1.0) -> None:
        """A setpoint change: owe the travel the plant's gain says it needs at once (``ff_s`` per unit
        relative change; ``sign`` -1 for speeds: a lower speed needs more brake; +1 for torque)."""
        if self.g.ff_s > 0 and old_setpoint > 0 and new_setpoint > 0:
            self.owed_s += sign * self.g.ff_s * (new_setpoint - old_setpoint) / old_setpoint

    def command(self, e: float, dt_s: float) -> float:
        """Actuator command in [-1, 1] for the relative error ``e`` (+: apply more brake)."""
        if not math.isfinite(e):
            return 0.0
        u = self.g.kp * e + self.g.ki_per_s * self.integral
        if self.g.lead_s and dt_s > 0:
            n = max(1, round(self.g.derivative_window_s / dt_s))
            self.e_hist.append(e)
            del self.e_hist[:-(n + 1)]
            rate = (e - self.e_hist[0]) / (dt_s * (len(self.e_hist) - 1)) if len(self.e_hist) > 1 else 0.0
            self.e_lead = e + self.g.lead_s * rate
            u += self.g.kp * self.g.lead_s * rate
        saturated = abs(u) >= 1.0 and math.copysign(1.0, u) == math.copysign(1.0, e)
        if self.g.ki_per_s and not saturated:  # anti-windup: no integration into a saturated command
            self.integral += e * dt_s
        return max(-1.0, min(1.0, u))

    def pulse(self, u: float, e_rel: float) -> tuple[int, float]:
        """(direction, on-time in s) for command ``u`` over one period.

        Sigma-delta: the travel asked for accumulates until it is worth a pulse of at
        least ``min_pulse_s``, so a small command still moves the brake (slowly) instead
        of being lost under the minimum pulse.

        Inside the dead band nothing moves, but the travel already owed is kept while the
        error stays on the same side (dropped when it changes side: the ask is stale).
        Dropping it made every exit from the band start from zero: at the band's edge
        ``kp·e·T`` is 0.6 ms a period, so the first pulse came 1.1-1.7 s after the error
        left the band while the brake's fade kept carrying the speed away (+0.05-0.07 %/s
        on the simulated rig): 5 % steps sat outside +-0.5 % for 3-8 s (63 of 160 on seeds
        1-40; 15 with the travel kept: docs/control.md "Resolution and drift").
        """
        if not math.isfinite(e_rel):
            self.owed_s = 0.0
            return STOP, 0.0
        if self.owed_s * u < 0:
            self.owed_s = 0.0
        e_band = self.e_lead if self.g.lead_s and math.isfinite(self.e_lead) else e_rel
        if abs(e_band) < self.g.deadband_rel:  # (with a lead: the error one lag ahead, where it is heading)
            return STOP, 0.0
        self.owed_s += u * self.g.period_s
        min_pulse_s = self.g.min_pulse_s
        if 0 < self.g.fine_pulse_s < min_pulse_s and abs(e_band) < self.g.fine_band_rel:
            # a reversal near the setpoint: the last correction crossed the whole dead band (one minimum pulse
            # is more than the band: the CVT's sheaves stuck in its shift friction), so go finer from here
            self.fine = self.fine or (self.last_dir * self.owed_s < 0)
            if self.fine:
                min_pulse_s = self.g.fine_pulse_s
        else:
            self.fine = False
        if abs(self.owed_s) < min_pulse_s:
            return STOP, 0.0
        on_s = min(abs(self.owed_s), self.g.period_s)
        direction = APPLY if self.owed_s > 0 else RELEASE
        self.owed_s -= math.copysign(on_s, self.owed_s)
        self.last_dir = 1 if direction == APPLY else -1
        return direction, on_s


@dataclass(frozen=True)
class SpeedHoldPlan:
    """The steady test under speed hold: setpoints from light load down the range."""

    points: int = 22
    low_rpm: float = 2000.0  # the last setpoint (secondary)
    high_margin: float = 0.04  # the first setpoint: this fraction below the no-load speed
    tolerance_rel: float = 0.0075  # "at the setpoint": within 0.75 % ...
    in_band_s: float = 0.8  # ... for this long, then measure
    # ... and steady: the speed's rate over the last ``settle_rate_window_s`` (two adjacent means) below this
    # fraction of the setpoint per second (0: the dwell alone).  A window started while the speed still moves
    # averages a transient: the CVT shifts under the frozen brake and the window is drift-skipped, time lost.
    settle_rate_rel_per_s: float = 0.0
    settle_rate_window_s: float = 0.3
    max_approach_s: float = 8.0  # then: near the setpoint, measure (flagged); far from it, skip it
    unholdable_rel: float = 0.02  # "far": the shift region, where a friction brake cannot hold a speed
    drift_rel: float = 0.02  # a window whose mean speed ends farther than this from the setpoint is no point
    spacing: float = 1.0  # setpoint i of n at high - (high - low) (i/(n-1))**spacing: < 1 spaces the light-load
    # (shift) region wider, where the torque hardly changes, and the cheap low-speed points closer
    contact_drop_rel: float = 0.01  # contact search: full-speed apply until the secondary drops 1 %
    contact_timeout_s: float = 10.0


def channel_rpm(ctx, channel: int, window_s: float) -> float:
    """A Hall channel's rpm by edge count over the last ``window_s`` (NaN before the first frame)."""
    now = ctx.device_now_us()
    if now is None:
        return math.nan
    rpm, _ = rpm_by_count(ctx.streams.edge_window(channel, now - int(window_s * 1e6), now))
    return rpm


def secondary_rpm(ctx, window_s: float) -> float:
    return channel_rpm(ctx, v1.CH_SECONDARY, window_s)


def engine_rpm(ctx, window_s: float) -> float:
    return channel_rpm(ctx, v1.CH_PRIMARY, window_s)


def brake_torque_nm(ctx, window_s: float) -> float:
    """Secondary torque from the ADC mean over the last ``window_s`` (error-bit conversions left out)."""
    now = ctx.device_now_us()
    cal = ctx.config.calibration
    if now is None or cal is None:
        return math.nan
    _, codes, status = ctx.streams.adc_window(now - int(window_s * 1e6), now)
    codes = codes[(status & v1.ADC_STATUS_ERR) == 0]
    return float(cal.torque_secondary_nm(codes.mean())) if codes.size else math.nan


#: what a hold can hold: (reader, sign of the error: + means "apply more brake")
VARIABLES = {"secondary": (secondary_rpm, 1.0), "engine": (engine_rpm, 1.0), "torque": (brake_torque_nm, -1.0)}


def measured(ctx, variable: str, window_s: float) -> float:
    return VARIABLES[variable][0](ctx, window_s)


def hold_error(ctx, variable: str, setpoint: float, window_s: float, sign: float | None = None) -> tuple[float, float]:
    """(measured value, relative error: + means the brake must apply) for ``variable``; ``sign`` -1 where
    more load raises the variable (the engine while the CVT back-shifts)."""
    x = measured(ctx, variable, window_s)
    if not (setpoint > 0) or not math.isfinite(x) or (variable != "torque" and not x > 0):
        return x, math.nan
    return x, (VARIABLES[variable][1] if sign is None else sign) * (x - setpoint) / setpoint


async def _hold_loop(ctx, hold: SpeedHold, target: dict, variable: str = "secondary") -> None:
    """Background task: one actuator pulse per period towards ``target['rpm']`` (the setpoint of
    ``variable``: secondary or engine rpm, or torque in N·m)."""
    g = hold.g
    last_sp = target["rpm"]
    while True:
        await ctx.checkpoint()
        if target.get("frozen"):
            await ctx.sleep(g.period_s)
            continue
        sp = target["rpm"]
        sign = target.get("sign", VARIABLES[variable][1])
        if sp != last_sp:
            hold.feed_forward(last_sp, sp, -sign)
            last_sp = sp
        x, e = hold_error(ctx, variable, sp, g.speed_window_s, sign)
        u = hold.command(e, g.period_s)
        direction, on_s = hold.pulse(u, e)
        target["last_rpm"] = x
        if direction == STOP:
            await ctx.sleep(g.period_s)
            continue
        ctx.brake(direction)
        target["pulsing"] = True
        try:
            await ctx.sleep(on_s)
        finally:
            ctx.brake(STOP)
            target["pulsing"], target["last_pulse_end_s"] = False, ctx.now()
        await ctx.sleep(max(0.0, g.period_s - on_s))


async def run_speed_hold(ctx, sh: SpeedHoldPlan | None = None, gains: SpeedHoldGains | None = None) -> None:
    """After the warm-up: hold each setpoint, measure while holding, record the point.

    Uses the controller's own measurement (uncertainty target, discards) and states:
    STEP = moving to the next setpoint, SETTLE = holding until in band, MEASURE.
    """
    p = ctx.plan
    sh = sh or ctx.config.speed_hold_plan or speed_hold_plan_of(p)
    hold = SpeedHold(gains or ctx.config.speed_hold_gains or gains_for(ctx, "secondary"))
    no_load = secondary_rpm(ctx, 1.0)
    high = no_load * (1.0 - sh.high_margin)
    low = max(sh.low_rpm, p.min_secondary_rpm * 1.05)
    if not (high > low):
        ctx.fail("error", f"speed hold: no-load secondary {no_load:.0f} rpm leaves no range above {low:.0f} rpm")
        return
    setpoints = [high + (low - high) * (i / max(1, sh.points - 1)) ** sh.spacing for i in range(sh.points)]
    # Contact search first: the pads start clear of the rotor (free travel), and creeping
    # across it at a fraction of full speed wastes seconds. Full-speed apply until it bites.
    ctx.phase(State.STEP, "speed hold: finding the brake's contact point")
    t_c = ctx.now()
    ctx.brake(APPLY)
    try:
        while secondary_rpm(ctx, hold.g.speed_window_s) > no_load * (1.0 - sh.contact_drop_rel):
            if ctx.now() - t_c > sh.contact_timeout_s:
                ctx.fail("error", f"speed hold: the brake did not slow the secondary in {sh.contact_timeout_s:g} s")
                return
            await ctx.sleep(0.02)
    finally:
        ctx.brake(STOP)
    ctx.log("contact", after_s=ctx.now() - t_c)
    ctx.mark_loaded()  # the pads bite: the CVT is loaded from here (warm-up criterion)
    target = {"rpm": setpoints[0], "last_rpm": math.nan}
    loop_task = ctx.hold_task(_hold_loop(ctx, hold, target), name="speed-hold")
    try:
        for sp in setpoints:
            if secondary_rpm(ctx, hold.g.speed_window_s) < sp * (1.0 - sh.unholdable_rel) and sp != setpoints[-1]:
                continue  # already below it (the CVT jumped past): next setpoint
            await hold_point(ctx, sp, sh, target, loop_task, hold.g.speed_window_s)
        ctx.phase(State.DONE, f"speed hold: {len(setpoints)} setpoints")
    finally:
        loop_task.cancel()
        await asyncio.gather(loop_task, return_exceptions=True)
        ctx.brake(STOP)


async def hold_point(ctx, sp: float, sh: SpeedHoldPlan, target: dict, loop_task, window_s: float,
                     unholdable_why: str = "the CVT's shift region", **skip_fields) -> tuple[dict | None, str | None]:
    """Hold the secondary at ``sp`` (``loop_task`` runs :func:`_hold_loop` on ``target``), then measure with
    the brake frozen and record the point.  Returns (the point, None), or (None, why) when there is no point
    at ``sp``: the why is logged as a ``skip`` document (with ``skip_fields``)."""
    p = ctx.plan

    def skip(reason: str) -> tuple[None, str]:
        ctx.log("skip", reason=reason, **skip_fields)
        return None, reason

    target["rpm"] = sp
    ctx.phase(State.STEP, f"speed hold: secondary to {sp:.0f} rpm")
    t0 = ctx.now()
    ctx.phase(State.SETTLE, f"holding {sp:.0f} rpm until within {sh.tolerance_rel:.1%}")
    in_band_since = None
    settled_by = "held"
    while True:
        await ctx.sleep(0.05)
        if loop_task.done():
            loop_task.result()  # re-raise: the control task failed
        rpm = secondary_rpm(ctx, window_s)
        if abs(rpm - sp) <= sh.tolerance_rel * sp:
            in_band_since = in_band_since if in_band_since is not None else ctx.now()
            if ctx.now() - in_band_since >= sh.in_band_s and steady(ctx, sp, sh):
                break
        else:
            in_band_since = None
        if ctx.now() - t0 > sh.max_approach_s:
            settled_by = "timeout"
            break
    settle_s = ctx.now() - t0
    if settled_by == "timeout" and abs(rpm - sp) > sh.unholdable_rel * sp:
        return skip(f"cannot hold {sp:.0f} rpm (secondary at {rpm:.0f} rpm after {settle_s:.1f} s): {unholdable_why}")
    # Measure with the brake where the hold put it: corrections during the window would
    # move the torque and the shift under the average (measured: CI 4-10x wider).
    target["frozen"] = True
    try:
        while target.get("pulsing"):  # a pulse under way ends first (its travel is not the window's)
            await ctx.sleep(0.005)
        since_s = _steady_tail_s(ctx, sh, target, settled_by, settle_s)
        point, host_t0, host_t1 = await ctx.measure(
            give_up=lambda: not abs(secondary_rpm(ctx, 0.5) - sp) <= sh.drift_rel * sp, since_s=since_s)
    finally:
        target["frozen"] = False
    point = _inertia_corrected(ctx, point)
    point.update(settled_by=settled_by, settle_s=settle_s, setpoint_rpm=sp)
    if point.get("gave_up") or not abs(point["rpm_secondary"] - sp) <= sh.drift_rel * sp:
        # The frozen brake let the CVT shift under the window (its hysteresis): the average
        # is of a transient, not a steady point; the truth check showed errors of 3 pp.
        return skip(f"secondary drifted to {point['rpm_secondary']:.0f} rpm while measuring at {sp:.0f} rpm: "
                    "not a steady point")
    if not point["torque_secondary_nm"] >= p.min_point_torque_nm:
        return skip(f"torque {point['torque_secondary_nm']:.2f} N m below {p.min_point_torque_nm} N m at {sp:.0f} rpm")
    ctx.record(point, host_t0, host_t1)
    return point, None


def _steady_tail_s(ctx, sh: SpeedHoldPlan, target: dict, settled_by: str, settle_s: float) -> float:
    """How far back the window may begin: the settle's rate criterion judged the last ``settle_rate_window_s``
    steady, and if the brake has not moved over it either, those data (in the streams) are the point's
    (~0.3 s a point, ~5 s a run).  Not after a timeout (nothing was judged steady)."""
    if settled_by != "held" or not sh.settle_rate_rel_per_s > 0:
        return 0.0
    quiet_s = ctx.now() - target.get("last_pulse_end_s", -math.inf)
    return max(0.0, min(sh.settle_rate_window_s, quiet_s, settle_s))


def _inertia_corrected(ctx, point: dict) -> dict:
    """The window's I·alpha correction (dyno.analysis.inertia): with the brake frozen the CVT may still
    shift under the window (its sheaves' stick-slip), the engine and the secondary accelerating; what the
    crank's inertia takes the map's torque does not pass to the CVT, and the gauge misses the secondary's."""
    from dyno.analysis.inertia import correct_inertia
    from dyno.rig.config import InertiaConfig

    inertia = ctx.config.inertia or InertiaConfig()  # rig.toml [inertia]: the one source
    return correct_inertia(point, ctx.streams, ctx.config.engine_map, inertia.engine_kg_m2, inertia.secondary_kg_m2)


def speed_rate_rel_per_s(ctx, sp: float, window_s: float) -> float:
    """The secondary's rate of change as a fraction of ``sp`` per second: the difference of the mean speeds
    over the last two adjacent ``window_s`` (edge counts: immune to the firing ripple) over ``window_s``."""
    now = ctx.device_now_us()
    if now is None or not sp > 0:
        return math.nan
    w_us = int(window_s * 1e6)
    recent, _ = rpm_by_count(ctx.streams.edge_window(v1.CH_SECONDARY, now - w_us, now))
    before, _ = rpm_by_count(ctx.streams.edge_window(v1.CH_SECONDARY, now - 2 * w_us, now - w_us))
    return (recent - before) / sp / window_s


def steady(ctx, sp: float, sh: SpeedHoldPlan) -> bool:
    """The settle's rate criterion (see :class:`SpeedHoldPlan`): True when off or met."""
    if not sh.settle_rate_rel_per_s > 0:
        return True
    return abs(speed_rate_rel_per_s(ctx, sp, sh.settle_rate_window_s)) <= sh.settle_rate_rel_per_s


def speed_hold_plan_of(plan) -> SpeedHoldPlan:
    """The [speed_hold] table of a plan (file) as a :class:`SpeedHoldPlan` (defaults otherwise)."""
    params = dict(getattr(plan, "params", None) or {})
    return SpeedHoldPlan(**params)


def gains_for(ctx, variable: str) -> SpeedHoldGains:
    """The rig's gains (``rig.toml`` [control], set on the controller by the app), else the defaults."""
    control = ctx.config.control
    return SpeedHoldGains.from_config(control, variable) if control is not None else SpeedHoldGains()
