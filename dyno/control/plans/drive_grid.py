"""The drive grid (plan ``drive-grid``): the drive train mapped over throttle x secondary speed.

For each throttle in ``throttles`` (a plan's ``[drive_grid]`` table): release the brake fully, set the
throttle, let the engine settle, and read the secondary's speed with the brake released -- the fastest
this throttle drives it.  Setpoints above that (less a margin) are *unreachable* at this throttle: each
is skipped with that reason (a property of the engine, not a fault).  Then find the brake's contact
point and, for each reachable secondary-speed setpoint, high to low, hold it and measure a point with
the speed hold's machinery (:func:`dyno.control.plans.speed_hold.hold_point`: the same stopping rule and CI,
the same skips where it cannot hold or the CVT drifts).  Every point records its throttle
(``throttle_frac``), so its efficiency comes from the engine map's curve at that throttle, or is null
with the reason.

Every cell's outcome is logged as a ``grid_cell`` document (throttle, setpoint, the point's index or
the reason there is none); :func:`dyno.analysis.drive_grid.grid_table` turns cells and points into the
run's ``drive_grid`` (in ``dyno run --json``, ``dyno replay --json`` and the report).
"""

from __future__ import annotations

from dataclasses import dataclass

from dyno.control.api import PlanContext, State
from dyno.control.outputs import RELEASE, STOP


@dataclass(frozen=True)
class DriveGridPlan:
    throttles: tuple = (1.0, 0.8, 0.6)  # throttle fractions, in the order run
    setpoints_rpm: tuple = (4200.0, 3800.0, 3400.0, 3000.0, 2600.0)  # secondary speeds, run high to low
    throttle_settle_s: float = 3.0  # after a throttle change, brake released: the engine and CVT settle
    release_s: float = 10.0  # release at most this long (the actuator's full stroke is ~8 s) ...
    release_quiet_s: float = 1.0  # ... or until the secondary has stopped rising for this long
    reach_margin_rel: float = 0.02  # a setpoint above (1 - this) x the released speed is unreachable
    contact_drop_rel: float = 0.01
    contact_timeout_s: float = 12.0
    # the speed hold's settings per setpoint (dyno.control.plans.speed_hold.SpeedHoldPlan)
    tolerance_rel: float = 0.0075
    in_band_s: float = 0.5
    max_approach_s: float = 6.0
    unholdable_rel: float = 0.02
    drift_rel: float = 0.02

    def check(self, err) -> None:
        """Plan-file checks beyond the types (``err(field, expected)`` makes the ConfigError)."""
        if not self.throttles or not all(0.0 < u <= 1.0 for u in self.throttles):
            raise err("throttles", f"a non-empty list of throttle fractions 0 < throttle <= 1, got {list(self.throttles)}")
        if not self.setpoints_rpm or not all(v > 0 for v in self.setpoints_rpm):
            raise err("setpoints_rpm", f"a non-empty list of secondary speeds > 0 rpm, got {list(self.setpoints_rpm)}")


async def release_brake(ctx: PlanContext, g: DriveGridPlan) -> float:
    """Release until the secondary has stopped rising for ``release_quiet_s`` (pads clear) or ``release_s``."""
    t0 = ctx.now()
    best, best_t = ctx.read.secondary_rpm(0.3), t0
    ctx.brake(RELEASE)
    try:
        while ctx.now() - t0 < g.release_s:
            await ctx.sleep(0.1)
            rs = ctx.read.secondary_rpm(0.3)
            if rs > best * 1.002:
                best, best_t = rs, ctx.now()
            elif ctx.now() - best_t >= g.release_quiet_s:
                break
    finally:
        ctx.brake(STOP)
    return ctx.now() - t0


async def run_drive_grid(ctx: PlanContext, g: DriveGridPlan) -> None:
    from dyno.analysis.drive_grid import grid_table
    from dyno.control.plans.speed_hold import SpeedHoldPlan, find_contact, hold_point

    sh = SpeedHoldPlan(tolerance_rel=g.tolerance_rel, in_band_s=g.in_band_s, max_approach_s=g.max_approach_s,
                       unholdable_rel=g.unholdable_rel, drift_rel=g.drift_rel)
    setpoints = sorted(g.setpoints_rpm, reverse=True)
    cells: list[dict] = []
    recorded: list[dict] = []

    def cell(u: float, sp: float, point: dict | None, reason: str | None) -> None:
        doc = {"throttle_frac": u, "setpoint_rpm": sp, "index": None if point is None else point["index"],
               "reason": reason}
        cells.append(doc)
        ctx.log("grid_cell", **doc)

    for u in g.throttles:
        ctx.phase(State.STEP, f"drive grid: throttle {u:.2f}, brake released")
        await release_brake(ctx, g)
        ctx.throttle(u)
        await ctx.sleep(g.throttle_settle_s)
        free_rpm = ctx.read.secondary_rpm(1.0)
        ctx.log("grid_throttle", throttle_frac=u, secondary_released_rpm=free_rpm)
        reach = [sp for sp in setpoints if sp <= free_rpm * (1.0 - g.reach_margin_rel)]
        for sp in setpoints:
            if sp not in reach:
                cell(u, sp, None, f"unreachable at throttle {u:.2f}: the engine drives the secondary to only "
                                  f"{free_rpm:.0f} rpm with the brake released")
        if not reach:
            continue
        if not await find_contact(ctx, g.contact_drop_rel, g.contact_timeout_s):
            return  # (aborted: the brake did not bite)
        try:
            for sp in reach:
                point, why = await hold_point(
                    ctx, sp, sh, throttle_frac=u, setpoint_rpm=sp,
                    unholdable_why=f"at throttle {u:.2f} the brake cannot hold the secondary there "
                                   "(the CVT's shift region, or clutch slip at a low governed speed)")
                cell(u, sp, point, why)
                if point is not None:
                    recorded.append(point)
        finally:
            ctx.brake(STOP)  # (ends the hold: the next throttle starts from a released brake)
    # (not _set_results: the grid is no characterisation document; the grid_cell documents are its record)
    ctx.set_results({"drive_grid": grid_table(cells, recorded)}, truths=False, log=False)
    ctx.phase(State.DONE, f"drive grid: {len(g.throttles)} throttles x {len(setpoints)} speeds, "
                            f"{sum(c['index'] is not None for c in cells)} points")
