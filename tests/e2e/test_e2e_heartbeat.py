"""The safety heartbeat services the outputs and feeds the watchdog every ~20 ms, polls or not: carried by
the polls while they flow (no wake-up of its own), on its own timer when they stop, and checks then."""

import asyncio

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.control.safety import SafetyLimits

from .conftest import QUICK_PLAN


def _run(tmp_path, stop_poller_at_s=None):
    ticks: list[float] = []
    periods: list[float] = []
    beats: list[float] = []
    polls: list[float] = []
    start: list[float] = []

    def setup(ctx):
        loop = asyncio.get_running_loop()
        act = ctx.controller.act
        real_tick = act.tick

        def tick(now_s):
            ticks.append(loop.time())
            periods.append(ctx.poller.poll_period_s)  # the rate in force (ARMED polls slower)
            return real_tick(now_s)

        act.tick = tick
        ctx.controller.heartbeat_hooks.append(lambda: beats.append(loop.time()))
        ctx.poller.listeners.append(lambda events, now_s: polls.append(loop.time()))
        start.append(loop.time())
        if stop_poller_at_s is not None:
            loop.call_later(stop_poller_at_s, ctx.poller.stop)

    captured = {}

    def _setup(ctx):
        captured["ctx"] = ctx
        setup(ctx)

    result = run_test(RunSpec(sim=True, seed=4, out_dir=tmp_path / "run", plan=QUICK_PLAN, setup=_setup,
                                 max_sim_s=120.0))
    return result, captured["ctx"], [(t - start[0], dt) for t, dt in zip(ticks, periods)], \
        [t - start[0] for t in beats], [t - start[0] for t in polls]


def test_outputs_serviced_and_watchdog_fed_every_check_period(tmp_path):
    result, ctx, ticks, beats, polls = _run(tmp_path)
    assert result["state"] == "done"
    period = SafetyLimits().check_period_s
    end = max(beats)
    beats = [t for t in beats if 1.0 < t < end]
    assert len(beats) > 300
    # Carried by the polls: every beat is at a poll's instant (the heartbeat task never woke on its
    # own), no closer than 3/4 of a check period and at most one poll period after a whole one.
    poll_times = set(polls)
    assert all(b in poll_times for b in beats)
    slowest_poll_s = max(dt for _, dt in ticks)
    gaps = [b - a for a, b in zip(beats, beats[1:])]
    assert min(gaps) >= 0.75 * period - 1e-9
    assert max(gaps) <= period + slowest_poll_s + 1e-9
    assert sum(abs(g - period) < 1e-6 for g in gaps) > 0.5 * len(gaps)  # full rate: every 3rd poll, 20 ms
    assert len([t for t, _ in ticks if 1.0 < t < end]) >= len(beats)  # each beat services the outputs


def test_when_polls_stop_the_heartbeat_checks_and_comms_lost_trips(tmp_path):
    stop_at = 20.0
    result, ctx, _, beats, _ = _run(tmp_path, stop_poller_at_s=stop_at)
    assert result["state"] == "aborted"
    abort = result["aborts"][0]
    assert abort["cause"] == "comms_lost" and "not polled" in abort["detail"]
    after = [t for t in beats if stop_at < t <= abort["trigger_s"]]
    period = SafetyLimits().check_period_s
    assert after and after[0] - stop_at <= period + 1e-6
    assert max(b - a for a, b in zip(after, after[1:])) <= period + 1e-6
    lim = SafetyLimits()
    assert abort["trigger_s"] - stop_at <= max(1.0, 4 * lim.comms_timeout_s) + period + 0.05
    m = ctx.sim.model
    assert m.throttle_frac == 0.0 and not m.engine_enabled
