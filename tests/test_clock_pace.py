"""A paced virtual loop (``dyno run --speed N``) keeps N x real time whatever its work costs, and says how late
it woke (dyno.clock.Pace)."""

import asyncio
import time

import pytest

from dyno.clock import Pace, run

pytestmark = pytest.mark.quick


def _busy(s: float) -> None:
    t_end = time.perf_counter() + s
    while time.perf_counter() < t_end:
        pass


def test_the_work_between_waits_does_not_slow_the_pace():
    """20 ticks of 20 ms virtual, each with 4 ms of work, at 2x: 0.2 s of wall time, not 0.28 s (a loop that
    slept each whole timeout after its work ran slow by the work's share)."""
    work_s: list[float] = []  # each tick's work as it really took (a loaded machine preempts a busy loop too)

    async def go():
        loop = asyncio.get_running_loop()
        t0 = time.monotonic()
        for _ in range(20):
            t_work = time.monotonic()
            _busy(0.004)
            work_s.append(time.monotonic() - t_work)
            await asyncio.sleep(0.020)
        return time.monotonic() - t0, loop.pace_stats()

    wall_s, pace = run(go(), virtual=True, speed=2.0)
    # the end is the last deadline (0.2 s) plus that wake-up's lateness, bounded by the latest one this run saw
    # (a loaded machine's scheduling), plus whatever work did not fit in its tick's 10 ms of wall time (none on a
    # quiet machine): never the work's 20 x 4 ms on top (0.28 s on a quiet machine)
    late_s = pace["late_max_ms"] / 1e3
    overrun_s = sum(max(0.0, w - 0.010) for w in work_s)
    assert 0.19 <= wall_s < 0.2 + late_s + overrun_s + 0.02, (wall_s, pace, work_s)
    assert pace["speed"] == 2.0 and pace["held"] >= 0.2 / (0.2 + late_s + overrun_s + 0.02) - 0.02, pace
    assert pace["wakes"] == 20 and pace["written_off_s"] == 0.0
    assert 0.0 <= pace["late_p99_ms"] <= pace["late_max_ms"]


def test_a_loop_that_cannot_keep_up_falls_behind_and_says_so():
    """Work of 15 ms per 10 ms tick at 1x: every wake-up is late, the pace held is ~2/3."""
    async def go():
        for _ in range(10):
            _busy(0.015)
            await asyncio.sleep(0.010)
        return asyncio.get_running_loop().pace_stats()

    pace = run(go(), virtual=True, speed=1.0)
    assert pace["held"] < 0.8 and pace["late_p99_ms"] > 4.0, pace


def test_a_long_stall_is_written_off_not_caught_up():
    p = Pace(1.0)
    p.wait(0.0, 0.001)
    _busy(0.15)  # past MAX_DEBT_S: the anchor moves on
    p.wait(0.001, 0.001)
    assert p.written_off_s > 0.1 and p.late_max_s > 0.1
    t0 = time.monotonic()
    p.wait(0.002, 0.010)  # on time again from the new anchor: a real 10 ms wait, no burst
    assert time.monotonic() - t0 >= 0.009


def test_an_unpaced_loop_has_no_pace():
    async def go():
        await asyncio.sleep(1.0)
        return asyncio.get_running_loop().pace_stats()

    assert run(go(), virtual=True) is None
