"""GpioActuators on gpiozero's mock pins with a fake clock."""

from __future__ import annotations

import dataclasses

import pytest

from dyno.control.outputs import APPLY, RELEASE, STOP, Actuators
from dyno.errors import SafetyAbort
from dyno.hw.outputs import END_STOP_OVERRUN_FRACTION, GpioActuators

from dyno.hw.testing import assert_direction_never_switched_with_enable_on, assert_settled_before_enable, gpio

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def on_intervals(log, pin):
    """[(t_on, t_off)] for one pin from the shared log."""
    out, t_on = [], None
    for t, name, v in log:
        if name != pin:
            continue
        if v and t_on is None:
            t_on = t
        elif not v and t_on is not None:
            out.append((t_on, t))
            t_on = None
    return out, t_on


def test_hw_implements_actuators_protocol(actuators):
    assert isinstance(actuators, Actuators)
    assert actuators.brake_full_stroke_s == 2.0


def test_hw_startup_is_safe_and_releases(actuators, rig, factory):
    a = actuators
    assert a.engine_killed and a.throttle_fraction == 0.0
    th = rig.throttle
    assert factory.pin(rig.pins.throttle_servo).state == pytest.approx(th.idle_pulse_us / th.frame_us)
    # energise_to_run: killed == relay de-energised
    assert factory.pin(rig.pins.engine_kill).state == 0
    assert factory.pin(rig.pins.brake_direction).state == 0  # release = relay at rest
    assert a.finish_release()
    assert a.released and factory.pin(rig.pins.brake_enable).state == 0
    (intervals, still_on) = on_intervals(factory.log, gpio(rig.pins.brake_enable))
    assert still_on is None and len(intervals) == 1
    # unknown position at start-up -> a full stroke plus the end-stop overrun
    assert intervals[0][1] - intervals[0][0] == pytest.approx(2.0 * (1 + END_STOP_OVERRUN_FRACTION))


def test_hw_step_lasts_the_time_asked(actuators, rig, factory, clock):
    a = actuators
    a.finish_release()
    factory.log.clear()
    a.step(APPLY, 0.25)
    intervals, still_on = on_intervals(factory.log, gpio(rig.pins.brake_enable))
    assert still_on is None
    assert [round(off - on, 9) for on, off in intervals] == [0.25]
    assert a.brake_position == pytest.approx(0.25 / 2.0)
    a.step(RELEASE, 0.1)
    intervals, _ = on_intervals(factory.log, gpio(rig.pins.brake_enable))
    assert round(intervals[-1][1] - intervals[-1][0], 9) == 0.1
    assert a.brake_position == pytest.approx(0.15 / 2.0)
    assert_direction_never_switched_with_enable_on(factory.log, rig)
    assert_settled_before_enable(factory.log, rig)


def test_hw_reversal_under_power_goes_through_off_and_settle(actuators, rig, factory, clock):
    a = actuators
    a.finish_release()
    a.brake(APPLY)
    for _ in range(40):
        clock.advance(0.01)
        a.tick(clock.now())
    assert factory.pin(rig.pins.brake_enable).state == 1
    a.brake(RELEASE)  # while powered in APPLY
    assert factory.pin(rig.pins.brake_enable).state == 0  # off at once
    assert factory.pin(rig.pins.brake_direction).state == 1  # relay not yet touched
    for _ in range(20):
        clock.advance(0.01)
        a.tick(clock.now())
    assert factory.pin(rig.pins.brake_direction).state == 0
    assert factory.pin(rig.pins.brake_enable).state == 1
    # rapid dithering must never break the rule either
    for i in range(200):
        a.brake((APPLY, RELEASE, STOP)[i % 3] if i % 7 else APPLY)
        clock.advance(0.004)
        a.tick(clock.now())
    a.brake(STOP)
    assert factory.pin(rig.pins.brake_enable).state == 0
    assert_direction_never_switched_with_enable_on(factory.log, rig)
    assert_settled_before_enable(factory.log, rig)


def test_hw_end_stop_de_energises(actuators, rig, factory, clock):
    a = actuators
    a.finish_release()
    a.brake(APPLY)
    for _ in range(400):  # 4 s of ticks for a 2 s stroke
        clock.advance(0.01)
        a.tick(clock.now())
    assert factory.pin(rig.pins.brake_enable).state == 0
    assert a.brake_position == 1.0
    intervals, _ = on_intervals(factory.log, gpio(rig.pins.brake_enable))
    assert intervals[-1][1] - intervals[-1][0] == pytest.approx(2.0 * (1 + END_STOP_OVERRUN_FRACTION), abs=0.011)


def test_hw_non_blocking_step_to_one_tick(actuators, rig, factory, clock):
    a = actuators
    a.finish_release()
    factory.log.clear()
    a.brake_step(APPLY, 0.2)
    for _ in range(100):
        clock.advance(0.005)
        a.tick()
    intervals, still_on = on_intervals(factory.log, gpio(rig.pins.brake_enable))
    assert still_on is None and len(intervals) == 1
    assert 0.2 - 1e-9 <= intervals[0][1] - intervals[0][0] <= 0.2 + 0.005 + 1e-9


def test_hw_throttle_end_points(actuators, rig, factory):
    th, pin = rig.throttle, factory.pin(rig.pins.throttle_servo)
    assert actuators.finish_release()  # (the ignition is held open until the start-up release has run)
    actuators.engine_kill(False)
    actuators.throttle(1.0)
    assert pin.state == pytest.approx(th.full_pulse_us / th.frame_us)
    actuators.throttle(0.5)
    assert pin.state == pytest.approx((th.full_pulse_us + th.idle_pulse_us) / 2 / th.frame_us)
    actuators.throttle(7)  # clamped
    assert pin.state == pytest.approx(th.full_pulse_us / th.frame_us)
    assert pin.frequency == pytest.approx(50.0)
    actuators.safe_state()
    assert pin.state == pytest.approx(th.idle_pulse_us / th.frame_us)
    assert factory.pin(rig.pins.engine_kill).state == 0


def test_hw_thesis_kill_wiring(rig, factory, clock):
    thesis = dataclasses.replace(rig, kill_relay="energise_to_kill")
    with GpioActuators(thesis, pin_factory=factory, clock=clock) as a:
        assert factory.pin(rig.pins.engine_kill).state == 1
        assert a.finish_release()
        a.engine_kill(False)
        assert factory.pin(rig.pins.engine_kill).state == 0


def test_hw_reset_pulse(actuators, rig, factory, clock):
    factory.log.clear()
    t0 = clock.now()
    actuators.reset_arduino()
    intervals, still_on = on_intervals(factory.log, gpio(rig.pins.arduino_reset))
    assert still_on is None and len(intervals) == 1
    assert intervals[0][1] - intervals[0][0] == pytest.approx(rig.reset.pulse_s)
    assert clock.now() - t0 == pytest.approx(rig.reset.pulse_s + rig.reset.boot_s)


def test_hw_latch_refuses_run_commands(actuators):
    actuators.safe_state(latch=True)
    for bad in (lambda: actuators.brake(APPLY), lambda: actuators.throttle(0.3),
                lambda: actuators.engine_kill(False)):
        with pytest.raises(SafetyAbort):
            bad()
    actuators.brake(RELEASE)  # always allowed
    with pytest.raises(SafetyAbort, match="release stroke is still running"):
        actuators.clear_latch()  # not while the release runs: the re-arm would let a command stop it
    assert actuators.latched
    assert actuators.finish_release()
    actuators.clear_latch()
    actuators.engine_kill(False)


def test_hw_close_leaves_nothing_energised(actuators, rig, factory, clock):
    a = actuators
    a.finish_release()
    a.engine_kill(False)
    a.throttle(0.8)
    a.brake(APPLY)
    clock.advance(0.1)
    a.tick()
    a.close()
    for name, bcm in rig.pins.as_dict().items():
        pin = factory.pin(bcm)
        assert pin.function == "input", name
        # last driven state before release: off (kill relay off == killed)
        driven = [v for t, n, v in factory.log if n == gpio(bcm)]
        if name != "throttle_servo":
            assert not driven or driven[-1] == 0.0, name


def test_hw_release_starts_one_settle_after_the_latch_without_waiting_for_a_beat(rig, factory):
    """The engine services the driver's relay sequence at the driver's own deadlines (DeadlineService):
    applied brake, latch, and no beat at all — the enable comes back on in the release direction one relay
    settle after the latch (not up to two ~15 ms beats later), and the stroke then ends de-energised."""
    import asyncio

    from dyno.clock import VirtualTimeLoop
    from dyno.control.outputs import DeadlineService
    from dyno.hw.outputs import GpioActuators

    loop = VirtualTimeLoop()

    class LoopClock:
        def now(self):
            return loop.time()

    act = GpioActuators(rig, pin_factory=factory, clock=LoopClock())
    service = DeadlineService()
    seen: dict = {}

    async def scenario():
        act.safe_state()  # the start of a run: a release from wherever the brake is
        service.start(act)
        await asyncio.sleep(rig.actuator.full_stroke_s + 0.5)
        assert act.released
        act.brake(APPLY)
        for _ in range(50):  # apply for ~0.5 s on beats
            await asyncio.sleep(0.01)
            act.tick()
        assert 0.1 < act.brake_position < 1.0 and factory.pin(rig.pins.brake_enable).state == 1
        t_latch = loop.time()
        act.safe_state(latch=True)
        service.start(act)
        while factory.pin(rig.pins.brake_enable).state == 0 and loop.time() < t_latch + 1.0:
            await asyncio.sleep(0.001)
        seen["enable_after_s"] = loop.time() - t_latch
        seen["direction"] = factory.pin(rig.pins.brake_direction).state
        await asyncio.sleep(rig.actuator.full_stroke_s + 0.5)

    try:
        loop.run_until_complete(scenario())
    finally:
        service.cancel()
        loop.close()
    settle = rig.actuator.relay_settle_s
    assert seen["direction"] == 0  # the release direction
    assert 2 * settle - 1e-3 <= seen["enable_after_s"] <= 2 * settle + 0.003, seen  # off, settle, relay, settle
    assert factory.pin(rig.pins.brake_enable).state == 0 and act.released
    assert act.release_basis == "full_stroke_time"
    act.close()
