"""The paced live session (``dyno ui --sim --speed N``) times its plan on the scaled clock: the plan keeps
its own durations (rig seconds: controller, meta.json, the screen's "measuring N s"), while the physics runs at
N x the loop's (wall) time."""

from __future__ import annotations

import asyncio
import json
import time

import pytest

from dyno.clock import LOOP_RIG_CLOCK, run
from dyno.control.api import State, TestPlan
from dyno.session.pacing import ScaledClock
from dyno.ui.session import LiveOptions, LiveSession

SPEED = 8.0


@pytest.mark.quick
def test_the_scaled_clock_sleeps_rig_seconds_over_speed_on_the_loop():
    async def main():
        loop = asyncio.get_running_loop()
        clock = ScaledClock(loop.time, 4.0)
        t_loop, t_rig = loop.time(), clock.now()
        await clock.sleep(2.0)
        scaled = (loop.time() - t_loop, clock.now() - t_rig)
        t_loop = loop.time()
        await LOOP_RIG_CLOCK.sleep(2.0)
        return scaled, (loop.time() - t_loop, LOOP_RIG_CLOCK.now() - loop.time())

    (loop_s, rig_s), (plain_loop_s, offset_s) = run(main(), virtual=True)
    assert loop_s == pytest.approx(0.5) and rig_s == pytest.approx(2.0)
    assert plain_loop_s == pytest.approx(2.0) and offset_s == 0.0  # unpaced: rig time is the loop's


async def _until(cond, timeout_s: float) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if cond():
            return True
        await asyncio.sleep(0.02)
    return cond()


def test_a_paced_session_keeps_the_plans_durations_while_the_physics_runs_speed_times_wall_time(tmp_path):
    plan = TestPlan()
    seen: list[tuple[State, float, float, str]] = []  # (state, sim truth time, loop time, reason) at each change
    stale: list[float] = []  # at each change: the rig clock's now less the truth's time (the last poll's)
    hiccup = {"max_s": 0.0}  # the loop's longest stall seen by a 20 ms ticker: its lateness, measured in this run

    async def ticker():
        loop = asyncio.get_running_loop()
        t = loop.time()
        while True:
            await asyncio.sleep(0.02)
            now = loop.time()
            hiccup["max_s"] = max(hiccup["max_s"], now - t - 0.02)
            t = now

    async def scenario():
        s = LiveSession(LiveOptions(sim=True, speed=SPEED, seed=3, out_dir=tmp_path / "run", plan=plan))
        def changed(c):
            seen.append((c.state, s.sim.model.t_s, s.loop.time(), c.reason))
            stale.append(max(0.0, s.sim_now() - s.sim.model.t_s))
        s.controller.listeners.append(changed)
        s.start()
        tick = asyncio.ensure_future(ticker())
        try:
            assert await _until(lambda: s.controller.state is State.ARMED, 30), s.controller.reason
            s.go()
            assert await _until(lambda: s.controller.points or s.controller.state in (State.DONE, State.ABORTED),
                                90), s.controller.reason
            assert s.controller.points, s.controller.reason
            label_s = s.state_elapsed_s()
            return s.controller.plan, s.controller.points[0], s.controller.time_scale, label_s, s.ctx.writer.run_dir
        finally:
            tick.cancel()
            await s.close("test")

    ctrl_plan, point, time_scale, _, run_dir = asyncio.run(scenario())
    # the plan is the plan's own, not divided by the speed: the controller's, and the run's record of it
    assert ctrl_plan == plan and ctrl_plan.warmup_s == 3.0 and ctrl_plan.measure_s == 3.0
    meta = json.loads((run_dir / "meta.json").read_text())
    assert meta["plan"]["warmup_s"] == 3.0 and meta["plan"]["max_measure_s"] == plan.max_measure_s
    assert meta["plan"]["settle_mode"] == plan.settle_mode  # (no forced fixed settling)
    assert time_scale == pytest.approx(1 / SPEED)
    measure = [r for st, _, _, r in seen if st is State.MEASURE]
    assert measure and measure[0].startswith(f"measuring {plan.measure_s:.0f}-{plan.max_measure_s:.0f} s")
    # the warm-up lasts the plan's 3 s in the simulated world's time, 3/SPEED s on the loop
    (_, sim_w, loop_w, _), = [x for x in seen if x[0] is State.WARMUP]
    _, sim_s, loop_s, _ = next(x for x in seen if x[0] is State.STEP)
    assert plan.warmup_s - 0.1 < sim_s - sim_w < plan.warmup_s + 1.0, (sim_s - sim_w)
    assert sim_s - sim_w == pytest.approx(SPEED * (loop_s - loop_w), rel=0.15, abs=0.5)
    # settling is detected from the data as unpaced (no forced fixed wait), timed in rig seconds: the point's
    # settle_s is the simulated world's time from SETTLE to MEASURE
    assert point["settled_by"] in ("detected", "timeout") and point["settle_s"] >= plan.settle.min_settle_s
    # (the point's own window: a window whose torque showed the brake not yet loading is no point, and the
    # plan steps again, so the point's MEASURE is the one entered at its window's host start)
    i_measure = min((i for i, x in enumerate(seen) if x[0] is State.MEASURE),
                    key=lambda i: abs(seen[i][2] - point["host_t_start_s"]))
    i_settle = max(i for i in range(i_measure) if seen[i][0] is State.SETTLE)
    # (the first point also waits out the plan's time at load after its settling: the run's own record of it)
    docs = [json.loads(line) for line in (run_dir / "documents.jsonl").read_text().splitlines()]
    warmup_wait_s = sum(d["wait_s"] for d in docs if d["type"] == "warmup_wait")
    sim_settle_s = seen[i_measure][1] - seen[i_settle][1] - warmup_wait_s
    # (the truth's time is the last poll's: each end lags by how stale that poll was at the change (an I/O thread
    # starved on a loaded machine), plus a loop stall x SPEED, all as measured in this run)
    margin_s = 0.15 + stale[i_settle] + stale[i_measure] + 2 * SPEED * hiccup["max_s"]
    assert abs(sim_settle_s - point["settle_s"]) < margin_s, (point["settle_s"], sim_settle_s, hiccup, stale)
    # the first point's window: at least the plan's measure_s of device (rig) time, over SPEED on the loop
    assert point["duration_s"] >= plan.measure_s - 0.05, point["duration_s"]
    host_window_s = point["host_t_end_s"] - point["host_t_start_s"]
    assert host_window_s == pytest.approx(point["duration_s"] / SPEED, rel=0.15, abs=0.1)
