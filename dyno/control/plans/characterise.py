"""The engagement / shift-out / full-shift characterisation (plan ``engagement``).

Procedure (docs/control.md, "Characterisation"): brake released (the pads' residual
drag is the light load), engine at idle with the secondary at rest; then a slow
throttle ramp -- the governor's set speed rises, so the engine speed ramps at
~20 rpm/s -- through engagement, lock-up and the shift, until the ratio has sat on
the high stop for a while.  The analysis (:mod:`dyno.analysis.shift_events`, pure)
runs on the raw Hall edges of the ramp; the results go to the run as a
``characterisation`` document and into ``dyno run --json``.  Then, optionally, a
back-shift: a brake step at full shift and the ratio's response.

The safety checks are the controller's, unchanged: they run on every poll, and an
abort cancels this coroutine.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from dyno.analysis import shift_events as se
from dyno.control.api import PlanContext, State
from dyno.control.outputs import APPLY, STOP
from dyno.protocol import v1


@dataclass(frozen=True)
class EngagementPlan:
    idle_s: float = 4.0  # engine at idle, secondary at rest, before the ramp
    throttle_rate_per_s: float = 0.01  # ~22 rpm/s of governed speed: quasi-static within ~10 rpm
    throttle_max: float = 0.9
    max_ramp_s: float = 120.0
    high_plateau_s: float = 3.0  # end the ramp once the ratio has been flat this long after the shift
    secondary_max_frac: float = 0.8  # ... or the secondary reaches this fraction of its over-speed limit
    back_shift: bool = True  # a brake step at full shift, the ratio's response
    back_shift_step_s: float = 2.0  # actuator on-time of the load step
    back_shift_watch_s: float = 4.0
    # Shift-out flatness across load: more ramps with the brake preset by these actuator on-times from
    # released (light loads: a load that holds the secondary past the 2,300 rpm safety check would trip it).
    flatness_apply_s: tuple = (0.5, 1.0)
    release_s: float = 9.0  # a full release stroke (8 s) and margin between ramps
    check_margin_rpm: float = 60.0  # no heavier load once engagement is this close to the Hall check speed


async def run_engagement(ctx: PlanContext, ep: EngagementPlan) -> None:
    ctx.phase(State.WARMUP, "idle, brake released: the secondary must be at rest")
    ctx.throttle(0.0)
    await ctx.sleep(ep.idle_s)
    if ctx.read.rpm(v1.CH_SECONDARY) > 0:
        ctx.fail("error", f"engagement: the secondary turns at idle ({ctx.read.rpm(v1.CH_PRIMARY):.0f} rpm "
                            "engine): the clutch engages below idle, nothing to characterise")
        return
    p, s, t0_dev, t1_dev, ended = await _ramp(ctx, ep)
    res = characterise_ramp(p, s, t0_dev, t1_dev)
    res["ramp_ended"] = ended
    res["throttle_rate_per_s"] = ep.throttle_rate_per_s
    res["shift_out_torque_nm"] = _torque_near(ctx, res.get("shift_out_t_us"))
    ctx.set_results(res, log=False)  # the sim's truths for the ramp's load, before the back-shift step
    if ep.back_shift and math.isfinite(res.get("full_shift_ratio", math.nan)):
        res["back_shift"] = await _back_shift(ctx, ep, res)
    if ep.flatness_apply_s:
        res["shift_out_vs_load"] = [_load_row(res)] + await _flatness(ctx, ep, res.get("engagement_rpm", math.nan))
        rows = res["shift_out_vs_load"]
        res["shift_out_flatness"] = se.flatness([r["torque_secondary_nm"] for r in rows],
                                                [r["shift_out_rpm"] for r in rows],
                                                [r.get("shift_out_rpm_ci95", math.nan) for r in rows])
        if all("shift_out_rpm_true" in r for r in rows):
            res["shift_out_flatness_true"] = se.flatness([r["torque_secondary_nm"] for r in rows],
                                                         [r["shift_out_rpm_true"] for r in rows])
    res.update(predicted_from_tune(ctx, [r["torque_secondary_nm"] for r in res.get("shift_out_vs_load", [])]
                                   or [res.get("shift_out_torque_nm", math.nan)]))
    ctx.throttle(0.0)
    res.pop("test_time_s", None)  # (the final figure's: the engine stamps it)
    ctx.set_results(res, truths=False)
    ctx.phase(State.DONE, "engagement characterised" if math.isfinite(res["engagement_rpm"])
                else "engagement not found in the ramp")


def _add_truths(ctx: PlanContext, r: dict) -> None:
    """Let the simulator annotate a flatness ramp's figures with its truths (no document; the run's final
    figures replace them)."""
    ctx.set_results(r, log=False)


async def _ramp(ctx: PlanContext, ep: EngagementPlan):
    """From idle with the secondary at rest: the throttle ramp; returns the ramp's edges and times."""
    ctx.phase(State.STEP, f"throttle ramp {ep.throttle_rate_per_s:g}/s through engagement and the shift")
    t0_rig = ctx.now()
    t0_dev = ctx.read.device_now_us()
    over_s = ctx.config.limits.overspeed_secondary_rpm * ep.secondary_max_frac
    recent: deque = deque()
    low_plateau = math.nan  # the live ratio once flat (+-1 %) for 1 s after engagement: the low stop
    ended = "throttle at its maximum"
    while True:
        el = ctx.now() - t0_rig
        u = min(ep.throttle_max, ep.throttle_rate_per_s * el)
        ctx.throttle(u, log=False)
        await ctx.sleep(0.1)
        r = ctx.read.ratio()
        recent.append((ctx.now(), r))
        while recent and recent[0][0] < ctx.now() - ep.high_plateau_s:
            recent.popleft()
        rs = [x for _, x in recent if math.isfinite(x)]
        last_1s = [x for t, x in recent if t > ctx.now() - 1.0 and math.isfinite(x)]
        if not math.isfinite(low_plateau) and len(last_1s) >= 9 and max(last_1s) < 1.01 * min(last_1s):
            low_plateau = float(np.median(last_1s))
        shifted = math.isfinite(low_plateau) and rs and max(rs) < 0.6 * low_plateau
        if shifted and len(rs) >= 0.9 * ep.high_plateau_s / 0.1 and (max(rs) - min(rs)) < 0.01 * min(rs):
            ended = f"ratio flat on the high stop for {ep.high_plateau_s:g} s"
            break
        if ctx.read.rpm(v1.CH_SECONDARY) > over_s:
            ended = f"secondary at {ep.secondary_max_frac:.0%} of its over-speed limit"
            break
        if u >= ep.throttle_max and el > ep.throttle_max / ep.throttle_rate_per_s + ep.high_plateau_s:
            break
        if el > ep.max_ramp_s:
            ended = f"ramp time cap {ep.max_ramp_s:g} s"
            break
    t1_dev = ctx.read.device_now_us()
    ctx.log("ramp", ended=ended, t_start_us=t0_dev, t_end_us=t1_dev, throttle_rate_per_s=ep.throttle_rate_per_s)
    p = ctx.read.edges(v1.CH_PRIMARY, t0_dev - 2_000_000, t1_dev)
    s = ctx.read.edges(v1.CH_SECONDARY, t0_dev - 2_000_000, t1_dev)
    return p, s, t0_dev, t1_dev, ended


def _torque_near(ctx: PlanContext, t_us, half_s: float = 0.5) -> float:
    """Mean secondary torque (N m) over +- ``half_s`` around ``t_us``."""
    if t_us is None:
        return math.nan
    return ctx.read.torque_between_nm(int(t_us - half_s * 1e6), int(t_us + half_s * 1e6))


def _load_row(r: dict) -> dict:
    row = {"torque_secondary_nm": r.get("shift_out_torque_nm", math.nan), "shift_out_rpm": r.get("shift_out_rpm"),
           "shift_out_rpm_ci95": r.get("shift_out_rpm_ci95"), "engagement_rpm": r.get("engagement_rpm")}
    for k in ("shift_out_rpm_true", "engagement_rpm_true"):
        if k in r:
            row[k] = r[k]
    return row


async def _flatness(ctx: PlanContext, ep: EngagementPlan, last_eng: float) -> list:
    """More ramps, each with the brake preset a little further: shift-out against load."""
    from dyno.control.outputs import RELEASE

    rows = []
    check_rpm = ctx.config.limits.secondary_check_primary_rpm
    for apply_s in ep.flatness_apply_s:
        # A heavier load engages higher: keep the engagement clear of the safety check's "the secondary
        # must turn" speed, which would (rightly) trip while the brake holds the secondary there.
        if not math.isfinite(last_eng) or last_eng > check_rpm - ep.check_margin_rpm:
            ctx.log("skip", reason=f"shift-out flatness: engagement {last_eng:.0f} rpm within "
                                     f"{ep.check_margin_rpm:g} rpm of the safety check at {check_rpm:.0f} rpm: "
                                     "no heavier load")
            break
        ctx.phase(State.STEP, f"shift-out flatness: brake preset {apply_s:g} s, back to idle")
        ctx.throttle(0.0)
        ctx.brake(RELEASE)
        try:
            await ctx.sleep(ep.release_s)
        finally:
            ctx.brake(STOP)
        ctx.brake(APPLY)
        try:
            await ctx.sleep(apply_s)
        finally:
            ctx.brake(STOP)
        t0 = ctx.now()
        while ctx.read.rpm(v1.CH_SECONDARY) > 0 and ctx.now() - t0 < 30.0:
            await ctx.sleep(0.1)
        await ctx.sleep(1.0)
        p, s, t0_dev, t1_dev, ended = await _ramp(ctx, ep)
        r = characterise_ramp(p, s, t0_dev, t1_dev)
        r["shift_out_torque_nm"] = _torque_near(ctx, r.get("shift_out_t_us"))
        _add_truths(ctx, r)
        row = _load_row(r)
        row.update(brake_apply_s=apply_s, ramp_ended=ended, curve=r.get("curve"))
        rows.append(row)
        last_eng = r.get("engagement_rpm", math.nan)
    ctx.throttle(0.0)
    return rows


def characterise_ramp(p_edges, s_edges, t0_us: int, t1_us: int) -> dict:
    """The figures of one ramp (pure: edges in, numbers out)."""
    p = np.asarray(p_edges, dtype=np.int64)
    s = np.asarray(s_edges, dtype=np.int64)
    series = se.ratio_series(p, s, t0_us, t1_us)
    rough = se.ratio_events(series, t0_us)
    eng = se.engagement(p, s, t0_us, low_ratio_guess=rough.get("low_ratio") or None)
    t_eng = eng["engagement_t_us"] if eng["engagement_t_us"] is not None else t0_us
    ev = se.ratio_events(series, t_eng)
    out = {k: v for k, v in eng.items() if k != "engagement_t_us"}
    out.update(ev)
    # the ramp's shift curve for the report: every 3rd window (0.3 s), the slipping start left out
    rp, ratio = series["rpm_primary"][::3], series["ratio"][::3]
    ok = np.isfinite(rp) & np.isfinite(ratio) & (ratio < 2.0 * ev["low_ratio"] if math.isfinite(ev["low_ratio"])
                                                 else np.isfinite(ratio))
    out["curve"] = {"rpm_primary": [round(float(v), 1) for v in rp[ok]],
                    "ratio": [round(float(v), 4) for v in ratio[ok]]}
    return out


async def _back_shift(ctx: PlanContext, ep: EngagementPlan, res: dict) -> dict:
    """At full shift: a brake load step; the ratio's rise (the CVT back-shifts) and its time."""
    r0 = ctx.read.ratio(0.5)
    t0 = ctx.now()
    ctx.brake(APPLY)
    try:
        await ctx.sleep(ep.back_shift_step_s)
    finally:
        ctx.brake(STOP)
    trace = []
    while ctx.now() - t0 < ep.back_shift_step_s + ep.back_shift_watch_s:
        await ctx.sleep(0.1)
        trace.append((ctx.now() - t0, ctx.read.ratio()))
    r1 = float(np.nanmedian([r for t, r in trace if t > trace[-1][0] - 1.0]))
    out = {"ratio_before": r0, "ratio_after": r1, "rpm_primary_after": ctx.read.rpm(v1.CH_PRIMARY),
           "rpm_secondary_after": ctx.read.rpm(v1.CH_SECONDARY), "t63_s": math.nan}
    if math.isfinite(r0) and r1 > r0:
        target = r0 + 0.63 * (r1 - r0)
        for t, r in trace:
            if r >= target:
                out["t63_s"] = t
                break
    return out


def predicted_from_tune(ctx: PlanContext, loads_nm=()) -> dict:
    """The tune's predicted engagement and shift-out (``ctx.config.shift_prediction``) beside the measured."""
    pred_of = ctx.config.shift_prediction
    if pred_of is None:
        return {}
    try:
        pred = {"engagement_rpm": pred_of.engagement_rpm(), "shift_out_rpm_full_load": pred_of.shift_out_rpm_full_load(),
                "ratio_low_stop": pred_of.ratio_low_stop, "ratio_high_stop": pred_of.ratio_high_stop}
        if loads_nm:
            pred["shift_out_rpm_at_load"] = [pred_of.shift_out_at_load_rpm(t) for t in loads_nm]
            pred["shift_out_rpm"] = pred["shift_out_rpm_at_load"][0]  # at the first (lightest) ramp's load
    except Exception as exc:  # noqa: BLE001  a prediction that fails is noted, the measurement stands
        return {"predicted": {"error": f"{type(exc).__name__}: {exc}"}}
    return {"predicted": pred, "tune": pred_of.tune_name}
