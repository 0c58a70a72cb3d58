"""Mode ``step``: the thesis's open-loop brake steps (the 2018 rig's procedure).

Full throttle (the engine's warm-up is behind us), then repeat: apply the brake for ``step_s``, stop,
wait for steady state (detected from the data, or the thesis's fixed 4 s), measure a point — until
the secondary falls below ``min_secondary_rpm`` or ``max_points`` are taken.  The step length adapts
so the run gives about ``target_points`` points over ``expected_secondary_span_rpm``.  Every duration
here comes from the plan and is waited in rig seconds (:meth:`~dyno.control.api.PlanContext.sleep`), the
time base of the device's streams the settling window is cut from.
"""

from __future__ import annotations

import math

from dyno.control.api import PlanContext, State, TestPlan
from dyno.control.outputs import APPLY, STOP
from dyno.protocol import v1


async def run_thesis_step(ctx: PlanContext, p: TestPlan) -> None:
    """The steps (module doc); ``p``: the plan, whose [test] fields are this mode's parameters."""
    step_s = p.step_s
    last_rs = ctx.read.rpm(v1.CH_SECONDARY)
    recorded = 0
    while True:
        await ctx.checkpoint()
        ctx.phase(State.STEP, f"brake step {step_s * 1e3:.0f} ms")
        ctx.brake(APPLY)
        await ctx.sleep(step_s)
        ctx.brake(STOP)
        await ctx.loaded()
        ctx.phase(State.SETTLE, "waiting for steady state")
        settled_by, settle_s = await settle(ctx)
        if await secondary_below(ctx, p.min_secondary_rpm):
            ctx.phase(State.DONE, f"secondary below {p.min_secondary_rpm:.0f} rpm")
            return
        point, host_t0, host_t1 = await ctx.measure()
        if not point["torque_secondary_nm"] >= p.min_point_torque_nm:
            ctx.log("skip", reason=f"torque {point['torque_secondary_nm']:.2f} N m below "
                                   f"{p.min_point_torque_nm} N m: brake not yet loading")
            step_s = adapt_step(p, step_s, math.nan, math.nan)
            continue
        point.update(settled_by=settled_by, settle_s=settle_s, step_s=step_s)
        ctx.record(point, host_t0, host_t1)
        recorded += 1
        rs = point["rpm_secondary"]
        step_s = adapt_step(p, step_s, last_rs, rs)
        last_rs = rs
        if not math.isnan(rs) and rs < p.min_secondary_rpm:
            ctx.phase(State.DONE, f"secondary below {p.min_secondary_rpm:.0f} rpm")
            return
        if recorded >= p.max_points:
            ctx.phase(State.DONE, f"{p.max_points} points")
            return


def adapt_step(p, step_s: float, rs_before: float, rs_after: float) -> float:
    """The next step's length, aiming at ~``target_points`` over the range: short steps lengthen (×1.5 when the
    secondary fell less than half the share), long ones shorten (×0.6 above 1.5 shares), within the plan's bounds."""
    if math.isnan(rs_before) or math.isnan(rs_after):
        return step_s
    want = p.expected_secondary_span_rpm / p.target_points
    got = rs_before - rs_after
    if got < 0.5 * want:
        return min(p.step_max_s, step_s * 1.5)
    if got > 1.5 * want:
        return max(p.step_min_s, step_s * 0.6)
    return step_s


async def secondary_below(ctx: PlanContext, rpm_min: float) -> bool:
    """The secondary really turns slower than ``rpm_min`` (measured by its edges, not a silent sensor)."""
    rs = ctx.read.rpm(v1.CH_SECONDARY)
    if rs >= rpm_min:
        return False
    if rs == 0.0 and ctx.read.channel_quiet_s(v1.CH_SECONDARY) < 2.0:
        # Silent, not slow: a dead sensor or a stall, which the safety monitor judges
        # within secondary_quiet_s; never read it as "the test has reached its end".
        await ctx.sleep(ctx.config.limits.secondary_quiet_s + 0.1)
        rs = ctx.read.rpm(v1.CH_SECONDARY)
    return rs < rpm_min


async def settle(ctx: PlanContext) -> tuple[str, float]:
    """SETTLE: the thesis's fixed wait, or until the speeds and torque are steady (:func:`is_settled`),
    the time cap, or the secondary below the plan's end.  Returns (how, rig seconds)."""
    p, c = ctx.plan, ctx.plan.settle
    t0 = ctx.now()
    if p.settle_mode == "fixed":
        await ctx.sleep(c.fixed_settle_s)
        return "fixed", c.fixed_settle_s
    await ctx.sleep(c.min_settle_s)
    while True:
        if ctx.now() - t0 >= c.window_s and ctx.read.settled(c):
            return "detected", ctx.now() - t0
        if ctx.now() - t0 >= c.max_settle_s:
            return "timeout", ctx.now() - t0
        if (ctx.read.rpm(v1.CH_SECONDARY) < p.min_secondary_rpm and ctx.now() - t0 > c.min_settle_s + 1
                and await secondary_below(ctx, p.min_secondary_rpm)):
            return "below_min", ctx.now() - t0
        await ctx.sleep(0.1)
