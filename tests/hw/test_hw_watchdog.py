"""The watchdog cannot die, and it catches a real blocked event loop on the real-rig path."""

from __future__ import annotations

import asyncio
import time

from dyno.clock import MonotonicClock
from dyno.hw.outputs import GpioActuators
from dyno.hw.safety import Watchdog
from dyno.hw.testing import RecordingFactory, gpio


def test_watchdog_survives_an_exception_in_its_look_and_still_trips_on_a_later_stall(rig, factory, clock):
    act = GpioActuators(rig, pin_factory=factory, clock=clock)
    act.finish_release()
    dog = Watchdog(act, 0.5, clock=clock)
    calls = {"n": 0}

    def flaky_level_check():
        calls["n"] += 1
        if calls["n"] == 1:
            raise OSError(5, "E-stop input read failed")

    dog.level_checks.append(flaky_level_check)
    act.tick()
    dog.check()  # the level check raises inside the look
    assert dog.errors and "OSError" in dog.errors[0]
    assert act.latched and act.engine_killed, "an exception in the watchdog is a safe state"
    # it keeps watching: re-arm as an operator would, then stall the loop
    act.finish_release()
    act.clear_latch()
    act.engine_kill(False)
    dog.tripped = False
    act.tick()
    clock.advance(0.4)
    assert not dog.check() and not act.engine_killed
    clock.advance(0.2)  # 0.6 s without a tick
    assert dog.check() and act.engine_killed and act.latched
    act.close()


def test_watchdog_thread_keeps_running_when_a_look_raises(rig, factory, clock):
    act = GpioActuators(rig, pin_factory=factory, clock=MonotonicClock())
    dog = Watchdog(act, 0.2, clock=MonotonicClock())
    looks = {"n": 0}

    def broken():
        looks["n"] += 1
        raise RuntimeError("every look raises")

    dog.level_checks.append(broken)
    dog.start_thread(period_s=0.005)
    try:
        t_end = time.monotonic() + 2.0
        while looks["n"] < 20 and time.monotonic() < t_end:
            time.sleep(0.01)
    finally:
        dog.stop_thread()
        act.close()
    assert looks["n"] >= 20, "the thread died after the first exception"
    # one record, counted: a stuck input must not flood the log (issue 36: ~40 ERROR lines a second)
    assert dog.errors == ["watchdog look failed: RuntimeError: every look raises"]
    assert dog.error_counts[dog.errors[0]] >= 20


class _NoNano:
    """An I²C bus with nothing on it: the rig's own output code runs without a firmware link."""

    def i2c_rdwr(self, *msgs):
        raise OSError(5, "no Nano here")

    def close(self):
        pass


def test_watchdog_thread_catches_a_real_blocked_event_loop_on_the_real_rig_path(rig):
    """HardwareRig on MockFactory, a real asyncio loop beating it, then the loop blocked (time.sleep):
    the kill pin and the enable must drop within watchdog_s + one watchdog period, in real time."""
    from dyno.hw.rig import HardwareRig

    clock = MonotonicClock()
    factory = RecordingFactory(clock)
    result: dict = {}

    async def main(hw):
        act = hw.actuators
        assert act.finish_release()  # the start-up release stroke (real time: the fixture's 2 s stroke)
        act.engine_kill(False)
        hw.watchdog.start_thread()
        for _ in range(20):  # a live loop beats every 20 ms
            act.tick()
            await asyncio.sleep(0.02)
        assert not act.engine_killed, "tripped while the loop was alive"
        result["blocked_at"] = time.monotonic()
        time.sleep(1.2)  # the loop blocks: no await, no tick
        result["resumed_at"] = time.monotonic()

    hw = HardwareRig(rig, pin_factory=factory, clock=clock, bus=_NoNano(), install_signals=False)
    with hw:
        asyncio.run(main(hw))
        wd = hw.watchdog
        kill = gpio(rig.pins.engine_kill)
        high_kills = rig.kill_relay == "energise_to_kill"
        killed_at = [t for t, pin, v in factory.log
                     if pin == kill and t >= result["blocked_at"] and (v >= 0.5) == high_kills]
        assert killed_at, "the watchdog never killed the engine while the loop was blocked"
        latency = killed_at[0] - result["blocked_at"]
        # the watchdog's own bound (a timeout and one look) plus the OS's scheduling of its thread, which a loaded
        # or slower 2-core machine stretches: 150 ms of it (a Pi with the service alone sees ~1 ms)
        assert latency <= wd.timeout_s + wd.period_s + 0.15, latency
        assert killed_at[0] < result["resumed_at"], "safed only after the loop came back"
        assert hw.actuators.latched


def test_watchdog_thread_sleeps_to_the_deadline_while_the_loop_beats_and_trips_at_the_timeout(rig, factory):
    """Kicked every 20 ms the thread looks about once per timeout (not every period: the idle host's wake-ups,
    issue 42); when the kicks stop it trips the timeout after the last one, within a few ms of thread wake-up."""
    act = GpioActuators(rig, pin_factory=factory, clock=MonotonicClock())
    dog = Watchdog(act, 0.2, clock=MonotonicClock())
    looks = {"n": 0, "tripped_at": None}
    step = dog.step

    def counted() -> None:
        looks["n"] += 1
        step()
        if dog.tripped and looks["tripped_at"] is None:
            looks["tripped_at"] = time.monotonic()

    dog.step = counted
    act.tick()
    dog.start_thread()  # period 10 ms: 100 looks in the second below at the old fixed rate
    try:
        t_end = time.monotonic() + 1.0
        while time.monotonic() < t_end:
            dog.kick()
            time.sleep(0.02)
        beating_looks = looks["n"]
        last_kick = time.monotonic()
        dog.kick()
        while looks["tripped_at"] is None and time.monotonic() < last_kick + 2.0:
            time.sleep(0.005)
    finally:
        dog.stop_thread()
        act.close()
    assert beating_looks <= 12, beating_looks
    assert looks["tripped_at"] is not None and act.engine_killed
    # the timeout, plus the thread's wake-up as a loaded or slower 2-core machine schedules it (150 ms of it)
    assert 0.2 <= looks["tripped_at"] - last_kick <= 0.2 + 0.15, looks["tripped_at"] - last_kick


def test_watchdog_thread_cuts_the_engine_while_the_frozen_loop_holds_the_drivers_lock(rig):
    """Issue 49: the loop freezes *inside* one of the driver's commands (holding its lock, as a deadlocked
    driver call would).  The watchdog thread's cut needs no lock: the kill pin and the throttle's idle pulse are
    written within watchdog_s + one period of the freeze, while the lock is still held; the rest of the safe
    state (the latch, the release) follows once the command returns."""
    from dyno.hw.rig import HardwareRig

    clock = MonotonicClock()
    factory = RecordingFactory(clock)
    result: dict = {}

    async def main(hw):
        act = hw.actuators
        assert act.finish_release()
        act.engine_kill(False)
        act.throttle(0.5)
        hw.watchdog.start_thread()
        for _ in range(10):
            act.tick()
            await asyncio.sleep(0.02)
        assert not act.engine_killed
        with act._held():  # frozen inside a driver command: the lock is held all along
            result["blocked_at"] = time.monotonic()
            time.sleep(1.2)
            result["resumed_at"] = time.monotonic()
        deadline = time.monotonic() + 10.0  # the watchdog thread, which waited for the lock, now latches
        while not act.latched and time.monotonic() < deadline:
            await asyncio.sleep(0.01)

    hw = HardwareRig(rig, pin_factory=factory, clock=clock, bus=_NoNano(), install_signals=False)
    with hw:
        asyncio.run(main(hw))
        wd = hw.watchdog
        kill, servo = gpio(rig.pins.engine_kill), gpio(rig.pins.throttle_servo)
        high_kills = rig.kill_relay == "energise_to_kill"
        killed_at = [t for t, pin, v in factory.log
                     if pin == kill and t >= result["blocked_at"] and (v >= 0.5) == high_kills]
        idle = rig.throttle.idle_pulse_us / rig.throttle.frame_us
        idle_at = [t for t, pin, v in factory.log if pin == servo and t >= result["blocked_at"]
                   and abs(v - idle) < 1e-9]
        assert killed_at and idle_at, "the watchdog waited for the lock the frozen loop held"
        assert killed_at[0] < result["resumed_at"] and idle_at[0] < result["resumed_at"]
        assert killed_at[0] - result["blocked_at"] <= wd.timeout_s + wd.period_s + 0.15  # (scheduling: see above)
        assert wd.tripped and hw.actuators.latched  # (the driver's own safe state, once the lock was free)


def test_the_watchdog_keeps_its_trip_and_the_sessions_beat_reports_it_once(rig, factory, clock):
    """The trip as the look saw it is the watchdog's own (``silent_s``, ``tripped_at_s``): the session's beat, given
    to the controller's constructor before the controller exists, reports it once as a watchdog abort (issue 50: no
    ``on_trip`` set on the rig's own watchdog after it is built); a look that raised has no ``silent_s``."""
    from dyno.session.safety import watchdog_beat

    act = GpioActuators(rig, pin_factory=factory, clock=clock)
    act.finish_release()
    seen = []
    dog = Watchdog(act, 0.5, clock=clock, on_trip=seen.append, level_checks=())
    aborts = []

    class Ctrl:
        def abort(self, cause, detail, t_s=None):
            aborts.append((cause, detail, t_s))

    ctrl = None
    beat = watchdog_beat(dog, lambda: ctrl, 0.5)
    ctrl = Ctrl()
    act.tick()
    beat()
    assert dog.silent_s is None and not aborts
    clock.advance(0.7)
    assert dog.check()
    assert dog.silent_s == seen[0] and dog.silent_s >= 0.7 and dog.tripped_at_s == clock.now()
    beat()
    beat()
    assert len(aborts) == 1 and aborts[0][0] == "watchdog" and aborts[0][2] == dog.tripped_at_s
    assert f"silent for {dog.silent_s:.3f} s" in aborts[0][1]

    def broken():
        raise OSError(5, "E-stop input read failed")

    act.finish_release()
    act.clear_latch()
    raised = Watchdog(act, 0.5, clock=clock, level_checks=(broken,))
    raised.check()
    assert raised.tripped and raised.silent_s is None and raised.tripped_at_s is None
    watchdog_beat(raised, lambda: ctrl, 0.5)()
    assert aborts[-1][0] == "watchdog" and "OSError" in aborts[-1][1] and aborts[-1][2] is None
    act.close()
