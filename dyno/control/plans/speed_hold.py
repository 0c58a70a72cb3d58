"""The steady test under a secondary-speed hold (mode ``speed-hold``): setpoints from light load down.

After the warm-up: find the brake's contact point (full-speed apply until the secondary drops
``contact_drop_rel``: the pads start clear of the rotor), then for each setpoint, from
``(1 - high_margin)`` × the no-load speed down to ``low_rpm``,

    n_i = n_high + (n_low - n_high) (i / (N - 1))^spacing,     i = 0 … N-1

hold it (``ctx.hold``: the engine's loop on the brake), measure with the brake frozen where the hold put
it (corrections under the average would move the torque and the shift), and record the point.  A
setpoint the hold cannot reach within ``unholdable_rel`` (the CVT's shift region, where a friction
brake cannot hold a speed) is skipped with the reason; so is a window under which the secondary drifts
more than ``drift_rel`` (the frozen brake let the CVT shift: an average of a transient).  The safety
checks run on every poll underneath, whatever the plan does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from dyno.control.api import PlanContext, SpeedHold, State
from dyno.control.outputs import APPLY, STOP


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


async def run_speed_hold(ctx: PlanContext, sh: SpeedHoldPlan) -> None:
    """After the warm-up: hold each setpoint, measure while holding, record the point (module doc).
    STEP: moving to the next setpoint; SETTLE: holding until in band; MEASURE."""
    p = ctx.plan
    no_load = ctx.read.secondary_rpm(1.0)
    high = no_load * (1.0 - sh.high_margin)
    low = max(sh.low_rpm, p.min_secondary_rpm * 1.05)
    if not (high > low):
        ctx.fail("error", f"speed hold: no-load secondary {no_load:.0f} rpm leaves no range above {low:.0f} rpm")
        return
    setpoints = [high + (low - high) * (i / max(1, sh.points - 1)) ** sh.spacing for i in range(sh.points)]
    ctx.phase(State.STEP, "speed hold: finding the brake's contact point")
    if not await find_contact(ctx, sh.contact_drop_rel, sh.contact_timeout_s):
        return
    try:
        for sp in setpoints:
            if ctx.read.secondary_rpm(0.15) < sp * (1.0 - sh.unholdable_rel) and sp != setpoints[-1]:
                continue  # already below it (the CVT jumped past): next setpoint
            await hold_point(ctx, sp, sh)
        ctx.phase(State.DONE, f"speed hold: {len(setpoints)} setpoints")
    finally:
        ctx.brake(STOP)


async def find_contact(ctx: PlanContext, drop_rel: float = 0.01, timeout_s: float = 10.0) -> bool:
    """Full-speed apply until the secondary drops ``drop_rel`` below its speed now (the pads bite); then the
    CVT is loaded (the warm-up at load's clock starts).  False (and the test failed) when it does not."""
    no_load = ctx.read.secondary_rpm(1.0)
    t_c = ctx.now()
    ctx.brake(APPLY)
    try:
        while ctx.read.secondary_rpm(0.15) > no_load * (1.0 - drop_rel):
            if ctx.now() - t_c > timeout_s:
                ctx.fail("error", f"the brake did not slow the secondary in {timeout_s:g} s")
                return False
            await ctx.sleep(0.02)
    finally:
        ctx.brake(STOP)
    ctx.log("contact", after_s=ctx.now() - t_c)
    await ctx.loaded()
    return True


async def hold_point(ctx: PlanContext, sp: float, sh: SpeedHoldPlan, unholdable_why: str = "the CVT's shift region",
                     **skip_fields) -> tuple[dict | None, str | None]:
    """Hold the secondary at ``sp``, then measure with the brake frozen and record the point.  Returns
    (the point, None), or (None, why) when there is no point at ``sp``: the why is logged as a ``skip``
    document (with ``skip_fields``)."""
    p = ctx.plan

    def skip(reason: str) -> tuple[None, str]:
        ctx.log("skip", reason=reason, **skip_fields)
        return None, reason

    ctx.phase(State.STEP, f"speed hold: secondary to {sp:.0f} rpm")
    ctx.phase(State.SETTLE, f"holding {sp:.0f} rpm until within {sh.tolerance_rel:.1%}")
    held = await ctx.hold(SpeedHold(sp, tolerance_rel=sh.tolerance_rel, in_band_s=sh.in_band_s,
                                    max_approach_s=sh.max_approach_s, settle_rate_rel_per_s=sh.settle_rate_rel_per_s,
                                    settle_rate_window_s=sh.settle_rate_window_s))
    settled_by = "held" if held.reached else "timeout"
    if not held.reached and abs(held.value - sp) > sh.unholdable_rel * sp:
        return skip(f"cannot hold {sp:.0f} rpm (secondary at {held.value:.0f} rpm after {held.settle_s:.1f} s): "
                    f"{unholdable_why}")
    since_s = steady_tail_s(sh, held.reached, held.quiet_s, held.settle_s)
    point, host_t0, host_t1 = await ctx.measure(
        give_up=lambda: not abs(ctx.read.secondary_rpm(0.5) - sp) <= sh.drift_rel * sp, since_s=since_s)
    point = ctx.read.inertia_corrected(point)
    point.update(settled_by=settled_by, settle_s=held.settle_s, setpoint_rpm=sp)
    if point.get("gave_up") or not abs(point["rpm_secondary"] - sp) <= sh.drift_rel * sp:
        return skip(f"secondary drifted to {point['rpm_secondary']:.0f} rpm while measuring at {sp:.0f} rpm: "
                    "not a steady point")
    if not point["torque_secondary_nm"] >= p.min_point_torque_nm:
        return skip(f"torque {point['torque_secondary_nm']:.2f} N m below {p.min_point_torque_nm} N m at {sp:.0f} rpm")
    ctx.record(point, host_t0, host_t1)
    return point, None


def steady_tail_s(sh: SpeedHoldPlan, reached: bool, quiet_s: float, settle_s: float) -> float:
    """How far back the window may begin: the settle's rate criterion judged the last
    ``settle_rate_window_s`` steady, and if the brake has not moved over it either, those data (in the
    streams) are the point's.  Not after a timeout (nothing was judged steady)."""
    if not reached or not sh.settle_rate_rel_per_s > 0:
        return 0.0
    return max(0.0, min(sh.settle_rate_window_s, quiet_s, settle_s))
