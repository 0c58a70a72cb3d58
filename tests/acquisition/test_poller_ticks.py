"""The poller's two tick paths: in its task on the loop (non-blocking bus) and a paced I/O thread (blocking bus)."""

import asyncio
import threading
import time

import pytest

from dyno.acquisition.poller import Poller
from dyno.acquisition.reader import make_reader
from dyno.clock import run
from dyno.sim.rig import SimRig
from dyno.transports.base import I2CTransport

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def _rig_and_poller(loop, *, blocking_io: bool, poll_hz: float = 150.0):
    t0 = loop.time()
    rig = SimRig(lambda: loop.time() - t0, seed=5)  # the sim's time from 0
    poller = Poller(make_reader("v2", I2CTransport(rig.bus, 0x03)), poll_hz=poll_hz, blocking_io=blocking_io)
    m = rig.model
    m.engine_enabled, m.throttle_frac = True, 0.6
    rig.start_engine()
    return rig, poller


@pytest.mark.parametrize("virtual", [True, False])
def test_loop_ticks_at_the_poll_rate_and_lose_nothing(virtual):
    async def go():
        loop = asyncio.get_running_loop()
        rig, poller = _rig_and_poller(loop, blocking_io=False)
        on_loop = []
        poller.listeners.append(lambda ev, now: on_loop.append(threading.get_ident()))
        task = asyncio.create_task(poller.run())
        await asyncio.sleep(2.0 if virtual else 1.0)
        poller.stop()
        await task
        return rig, poller, on_loop

    rig, poller, on_loop = run(go(), virtual=virtual)
    polls = poller.timing.summary()["polls"] + 1
    expected = 300 if virtual else 150
    assert abs(polls - expected) <= (1 if virtual else 0.3 * expected)
    if virtual:  # deterministic: the intervals are exactly the period
        assert poller.timing.summary()["max_ms"] == pytest.approx(1e3 / 150, abs=1e-6)
        (rate,) = poller.timing.by_rate()  # the whole run's figures at the one rate it polled at
        assert rate["nominal_hz"] == 150.0 and rate["polls"] == polls - 1
        assert rate["held_hz"] == pytest.approx(150.0, abs=1e-3)
        assert rate["jitter_p99_ms"] == rate["late_p99_ms"] == 0.0
    assert set(on_loop) == {threading.get_ident()}
    assert poller.reader.events_lost == 0
    assert sum(poller.streams.counts().values()) == rig.firmware.events_generated > 100


def test_io_thread_delivers_every_event_on_the_loop_in_real_time():
    """Blocking bus (the real rig): transfers in one I/O thread, streams/listeners on the loop."""
    async def go():
        loop = asyncio.get_running_loop()
        rig, poller = _rig_and_poller(loop, blocking_io=True)
        seen_threads, reader_threads = set(), set()
        poller.listeners.append(lambda ev, now: seen_threads.add(threading.get_ident()))
        real_poll = poller.reader.poll

        def poll(now_s):
            reader_threads.add(threading.current_thread().name)
            return real_poll(now_s)

        poller.reader.poll = poll
        task = asyncio.create_task(poller.run())
        await asyncio.sleep(1.0)
        poller.stop()
        await task
        await asyncio.sleep(0.2)  # a tick read before stop and handed over after it
        alive = [t for t in threading.enumerate() if t.name == "dyno-poller-io"]
        return rig, poller, seen_threads, reader_threads, alive

    rig, poller, seen_threads, reader_threads, alive = run(go(), virtual=False)
    assert seen_threads == {threading.get_ident()}, "listeners (safety, run log) must run on the loop"
    assert reader_threads == {"dyno-poller-io"}, "bus transfers must not run on the loop"
    assert not alive, "the I/O thread ends after stop"
    assert 100 <= poller.timing.summary()["polls"] <= 200
    assert poller.reader.events_lost == 0
    # every event the device handed over reached the streams exactly once (none dropped at stop)
    # the sim advances only on bus transfers, so after the last one every event it generated has
    # been read: each must have reached the streams exactly once (none dropped at stop)
    assert sum(poller.streams.counts().values()) == rig.firmware.events_generated > 100


def test_poll_timing_by_rate_holds_the_whole_run_at_each_rate():
    """The rate held and the jitter per nominal rate, over every interval (the kept list is bounded)."""
    from dyno.acquisition.poller import PollTiming

    t = PollTiming(keep=100)
    for _ in range(970):
        t.add(1 / 150, 1 / 150)
    for _ in range(30):  # 3 % of the ticks 20 ms apart: the poller fell behind and skipped
        t.add(0.020, 1 / 150)
    for _ in range(50):
        t.add(0.020, 3 / 150)  # the waiting states' 50 Hz
    fast, slow = sorted(t.by_rate(), key=lambda r: -r["nominal_hz"])
    assert fast["polls"] == 1000 and slow["polls"] == 50 and slow["held_hz"] == pytest.approx(50.0)
    assert fast["held_hz"] == pytest.approx(1000 / (970 / 150 + 30 * 0.020), abs=1e-3)
    assert fast["jitter_p99_ms"] == pytest.approx(20.0 - 1e3 / 150, abs=0.02)
    assert fast["late_p99_ms"] == pytest.approx(20.0 - 1e3 / 150, abs=0.02)
    assert fast["max_ms"] == pytest.approx(20.0)
    assert len(t.intervals_s) <= 100 and t.summary()["by_rate"] == t.by_rate()


@pytest.mark.parametrize("blocking_io", [False, True])
def test_a_failing_read_ends_run_with_its_exception(blocking_io):
    class Broken(Exception):
        pass

    async def go():
        loop = asyncio.get_running_loop()
        _, poller = _rig_and_poller(loop, blocking_io=blocking_io)
        calls = {"n": 0}
        real_poll = poller.reader.poll

        def poll(now_s):
            calls["n"] += 1
            if calls["n"] == 20:
                raise Broken("bus driver bug")
            return real_poll(now_s)

        poller.reader.poll = poll
        with pytest.raises(Broken):
            await asyncio.wait_for(poller.run(), 5.0)
        return calls["n"]

    assert run(go(), virtual=False) >= 20


def test_a_hung_transfer_blocks_only_the_io_thread():
    """A transfer stuck in the kernel must not freeze the loop: the heartbeat must see the silence."""
    release = threading.Event()

    async def go():
        loop = asyncio.get_running_loop()
        _, poller = _rig_and_poller(loop, blocking_io=True)
        real_poll = poller.reader.poll
        hang_from = {"t": None}

        def poll(now_s):
            if hang_from["t"] is not None and time.monotonic() >= hang_from["t"]:
                release.wait(2.0)  # the bus hangs
            return real_poll(now_s)

        poller.reader.poll = poll
        task = asyncio.create_task(poller.run())
        await asyncio.sleep(0.3)
        hang_from["t"] = time.monotonic()
        beats = []
        t0 = loop.time()
        while loop.time() - t0 < 0.5:  # the loop keeps beating through the hang
            await asyncio.sleep(0.01)
            beats.append(loop.time())
        silent_s = loop.time() - poller.last_valid_frame_s
        release.set()
        poller.stop()
        await task
        return beats, silent_s

    beats, silent_s = run(go(), virtual=False)
    gaps = [b - a for a, b in zip(beats, beats[1:])]
    assert len(beats) >= 30 and max(gaps) < 0.1
    assert silent_s > 0.4  # what comms_lost (0.25 s) is judged on
