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


def _live_ratio(ctrl, window_s: float = 0.3) -> float:
    now = ctrl.poller.device_now_us()
    if now is None:
        return math.nan
    st = ctrl.poller.streams
    rp = se.rpm_at(st.edge_window(v1.CH_PRIMARY, now - int(window_s * 1e6), now), now - window_s * 5e5, window_s * 5e5)
    rs = se.rpm_at(st.edge_window(v1.CH_SECONDARY, now - int(window_s * 1e6), now), now - window_s * 5e5,
                   window_s * 5e5)
    return rp / rs if rs > 0 else math.nan


async def run_engagement(ctrl, ep: EngagementPlan | None = None) -> None:
    from dyno.control.controller import State

    ep = ep or getattr(ctrl, "engagement_plan", None) or EngagementPlan()
    ctrl._enter(State.WARMUP, "idle, brake released: the secondary must be at rest")
    ctrl.act.throttle(0.0)
    await ctrl._sleep(ep.idle_s)
    if ctrl.poller.rpm(v1.CH_SECONDARY) > 0:
        ctrl.abort("error", f"engagement: the secondary turns at idle ({ctrl.poller.rpm(v1.CH_PRIMARY):.0f} rpm "
                            "engine): the clutch engages below idle, nothing to characterise")
        return
    ctrl._enter(State.STEP, f"throttle ramp {ep.throttle_rate_per_s:g}/s through engagement and the shift")
    t0_host = ctrl._now()
    t0_dev = ctrl.poller.device_now_us()
    over_s = getattr(ctrl.limits, "overspeed_secondary_rpm", 7800.0) * ep.secondary_max_frac
    recent: deque = deque()
    low_plateau = math.nan  # the live ratio once flat (+-1 %) for 1 s after engagement: the low stop
    ended = "throttle at its maximum"
    while True:
        el = ctrl._now() - t0_host
        u = min(ep.throttle_max, ep.throttle_rate_per_s * el)
        ctrl.act.throttle(u)
        await ctrl._sleep(0.1)
        r = _live_ratio(ctrl)
        recent.append((ctrl._now(), r))
        while recent and recent[0][0] < ctrl._now() - ep.high_plateau_s:
            recent.popleft()
        rs = [x for _, x in recent if math.isfinite(x)]
        last_1s = [x for t, x in recent if t > ctrl._now() - 1.0 and math.isfinite(x)]
        if not math.isfinite(low_plateau) and len(last_1s) >= 9 and max(last_1s) < 1.01 * min(last_1s):
            low_plateau = float(np.median(last_1s))
        shifted = math.isfinite(low_plateau) and rs and max(rs) < 0.6 * low_plateau
        if shifted and len(rs) >= 0.9 * ep.high_plateau_s / 0.1 and (max(rs) - min(rs)) < 0.01 * min(rs):
            ended = f"ratio flat on the high stop for {ep.high_plateau_s:g} s"
            break
        if ctrl.poller.rpm(v1.CH_SECONDARY) > over_s:
            ended = f"secondary at {ep.secondary_max_frac:.0%} of its over-speed limit"
            break
        if u >= ep.throttle_max and el > ep.throttle_max / ep.throttle_rate_per_s + ep.high_plateau_s:
            break
        if el > ep.max_ramp_s:
            ended = f"ramp time cap {ep.max_ramp_s:g} s"
            break
    t1_dev = ctrl.poller.device_now_us()
    ctrl._log("ramp", ended=ended, t_start_us=t0_dev, t_end_us=t1_dev, throttle_rate_per_s=ep.throttle_rate_per_s)
    st = ctrl.poller.streams
    p = st.edge_window(v1.CH_PRIMARY, t0_dev - 2_000_000, t1_dev)
    s = st.edge_window(v1.CH_SECONDARY, t0_dev - 2_000_000, t1_dev)
    res = characterise_ramp(p, s, t0_dev, t1_dev)
    res["ramp_ended"] = ended
    res["throttle_rate_per_s"] = ep.throttle_rate_per_s
    for hook in ctrl.result_hooks:  # the sim's truths for the ramp's load, before the back-shift step
        hook(res)
    if ep.back_shift and math.isfinite(res.get("full_shift_ratio", math.nan)):
        res["back_shift"] = await _back_shift(ctrl, ep, res)
    res.update(predicted_from_tune(ctrl))
    ctrl.act.throttle(0.0)
    res["test_time_s"] = ctrl._now() - ctrl.go_s
    ctrl._set_results(res, hooks=False)
    ctrl._enter(State.DONE, "engagement characterised" if math.isfinite(res["engagement_rpm"])
                else "engagement not found in the ramp")


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
    return out


async def _back_shift(ctrl, ep: EngagementPlan, res: dict) -> dict:
    """At full shift: a brake load step; the ratio's rise (the CVT back-shifts) and its time."""
    r0 = _live_ratio(ctrl, 0.5)
    t0 = ctrl._now()
    ctrl.act.brake(APPLY)
    try:
        await ctrl._sleep(ep.back_shift_step_s)
    finally:
        ctrl.act.brake(STOP)
    trace = []
    while ctrl._now() - t0 < ep.back_shift_step_s + ep.back_shift_watch_s:
        await ctrl._sleep(0.1)
        trace.append((ctrl._now() - t0, _live_ratio(ctrl)))
    r1 = float(np.nanmedian([r for t, r in trace if t > trace[-1][0] - 1.0]))
    out = {"ratio_before": r0, "ratio_after": r1, "rpm_primary_after": ctrl.poller.rpm(v1.CH_PRIMARY),
           "rpm_secondary_after": ctrl.poller.rpm(v1.CH_SECONDARY), "t63_s": math.nan}
    if math.isfinite(r0) and r1 > r0:
        target = r0 + 0.63 * (r1 - r0)
        for t, r in trace:
            if r >= target:
                out["t63_s"] = t
                break
    return out


def predicted_from_tune(ctrl) -> dict:
    """The tune's predicted engagement and shift-out (dyno.tuning) and the measured minus predicted."""
    tune_path = getattr(ctrl, "tune_path", None)
    src = getattr(ctrl.engine_map, "source", None)
    if not tune_path or not src:
        return {}
    try:
        from dyno.tuning.shift_curve import Solver, load_engine_map, model_params_for
        from dyno.tuning.tune import load_tune

        tune = load_tune(tune_path)
        solver = Solver(tune, load_engine_map(src), model_params_for(tune))
        pred = {"engagement_rpm": solver.engagement_rpm(),
                "shift_out_rpm_full_load": solver.balance_rpm(solver.ratio_low_stop),
                "ratio_low_stop": solver.ratio_low_stop, "ratio_high_stop": solver.ratio_high_stop}
    except Exception as exc:  # noqa: BLE001  a prediction that fails is noted, the measurement stands
        return {"predicted": {"error": f"{type(exc).__name__}: {exc}"}}
    return {"predicted": pred, "tune": tune.name}
