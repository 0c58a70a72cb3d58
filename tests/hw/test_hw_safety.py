"""The safe state is reached on every path: start-up, exit, exception, signals, dead loop."""

from __future__ import annotations

import asyncio
import dataclasses
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from dyno.control.outputs import APPLY
from dyno.clock import MonotonicClock
from dyno.hw.outputs import GpioActuators
from dyno.hw.safety import SafetyGuard, Watchdog
from dyno.hw.testing import assert_direction_never_switched_with_enable_on, assert_settled_before_enable, gpio

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

REPO = Path(__file__).resolve().parents[2]


def assert_safe_and_de_energised(factory, rig, act):
    """Throttle idle, killed, brake released, then nothing energised and pins released."""
    assert act.closed
    assert act.engine_killed and act.throttle_fraction == 0.0
    assert act.brake_position == 0.0
    last = {}
    for _, name, v in factory.log:
        last[name] = v
    for name in ("brake_enable", "brake_direction", "arduino_reset", "engine_kill"):
        assert last.get(gpio(getattr(rig.pins, name)), 0.0) == 0.0, name
    for bcm in rig.pins.as_dict().values():
        assert factory.pin(bcm).function == "input"
    assert_direction_never_switched_with_enable_on(factory.log, rig)
    assert_settled_before_enable(factory.log, rig)


def drive(act, clock, seconds=0.3):
    act.engine_kill(False)
    act.throttle(0.7)
    act.brake(APPLY)
    for _ in range(int(seconds / 0.01)):
        clock.advance(0.01)
        act.tick()


def test_hw_safe_on_startup_and_normal_exit(rig, factory, clock):
    act = GpioActuators(rig, pin_factory=factory, clock=clock)
    with SafetyGuard(act, use_atexit=False):
        assert act.engine_killed and act.throttle_fraction == 0.0
        assert factory.pin(rig.pins.brake_enable).state == 1  # start-up release stroke under way
        act.finish_release()
        drive(act, clock)
        assert factory.pin(rig.pins.brake_enable).state == 1
    assert_safe_and_de_energised(factory, rig, act)


def test_hw_safe_on_exception_mid_step(rig, factory, clock):
    act = GpioActuators(rig, pin_factory=factory, clock=clock)
    with pytest.raises(RuntimeError, match="boom"):
        with SafetyGuard(act, use_atexit=False):
            act.finish_release()
            act.engine_kill(False)
            def explode(c, s):
                # first sleep with the actuator powered: the middle of the step
                if factory.pin(rig.pins.brake_enable).state:
                    c.on_sleep = None
                    raise RuntimeError("boom")

            clock.on_sleep = explode
            act.step(APPLY, 1.0)
        pytest.fail("step() finished without the injected exception")
    assert factory.pin(rig.pins.brake_enable).function == "input"
    assert_safe_and_de_energised(factory, rig, act)


def test_hw_exception_during_long_step_with_signal_in_the_middle(rig, factory, clock):
    """SIGTERM (via the handler function) arriving while step() sleeps."""
    act = GpioActuators(rig, pin_factory=factory, clock=clock)
    guard = SafetyGuard(act, use_atexit=False)
    with pytest.raises(SystemExit) as exc:
        with guard:
            act.finish_release()
            act.engine_kill(False)
            act.throttle(0.5)

            def deliver(c, s):
                if act.brake_position > 0 or factory.pin(rig.pins.brake_enable).state:
                    c.on_sleep = None
                    guard.handle_signal(signal.SIGTERM)

            clock.on_sleep = deliver
            act.step(APPLY, 1.0)
    assert exc.value.code == 128 + signal.SIGTERM
    assert guard.signal_received == signal.SIGTERM
    assert_safe_and_de_energised(factory, rig, act)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_hw_installed_handler_catches_real_signal(rig, factory, clock, sig):
    act = GpioActuators(rig, pin_factory=factory, clock=clock)
    before = signal.getsignal(sig)
    with pytest.raises(SystemExit) as exc:
        with SafetyGuard(act, use_atexit=False):
            act.finish_release()
            drive(act, clock)
            os.kill(os.getpid(), sig)  # handler runs in this (main) thread at the next bytecode
            for _ in range(1000):
                pass
    assert exc.value.code == 128 + sig
    assert signal.getsignal(sig) is before  # handler restored
    assert_safe_and_de_energised(factory, rig, act)


CHILD = textwrap.dedent("""
    import json, sys, time
    from gpiozero import Device
    from dyno.clock import FakeClock
    from dyno.hw.outputs import GpioActuators
    from dyno.hw.safety import SafetyGuard
    from dyno.hw.testing import RecordingFactory
    from dyno.rig.config import load_rig
    from dyno.control.outputs import APPLY
    clock = FakeClock()
    f = RecordingFactory(clock)
    Device.pin_factory = f
    rig = load_rig()
    act = GpioActuators(rig, pin_factory=f, clock=clock)
    try:
        with SafetyGuard(act):
            act.finish_release()
            act.engine_kill(False)
            act.throttle(0.6)
            act.brake(APPLY)
            print("ready", flush=True)
            while True:               # a control loop, killed from outside
                time.sleep(0.005)
                clock.advance(0.005)
                act.tick()
    finally:
        print(json.dumps({"log": f.log, "closed": act.closed, "killed": act.engine_killed,
                          "position": act.brake_position,
                          "functions": {str(b): f.pin(b).function for b in rig.pins.as_dict().values()}}),
              flush=True)
""")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_hw_signal_to_subprocess(rig, sig):
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, env=env, cwd=REPO)
    try:
        assert p.stdout.readline().strip() == "ready"
        p.send_signal(sig)
        out, err = p.communicate(timeout=20)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 128 + sig, err
    state = json.loads(out.strip().splitlines()[-1])
    assert state["closed"] and state["killed"] and state["position"] == 0.0
    assert set(state["functions"].values()) == {"input"}
    log = [tuple(x) for x in state["log"]]
    last = {}
    for _, name, v in log:
        last[name] = v
    for name in ("brake_enable", "brake_direction", "arduino_reset", "engine_kill"):
        assert last.get(gpio(getattr(rig.pins, name)), 0.0) == 0.0, name
    assert_direction_never_switched_with_enable_on(log, rig)


def test_hw_watchdog_trips_when_control_loop_dies(rig, factory):
    # Real time here (the asyncio loop sleeps for real), so a short stroke.
    fast = dataclasses.replace(rig, actuator=dataclasses.replace(
        rig.actuator, full_stroke_s=0.1, relay_settle_s=0.005, watchdog_s=0.05))
    clock = MonotonicClock()
    factory.clock = clock
    act = GpioActuators(fast, pin_factory=factory, clock=clock)
    act.finish_release()
    trips = []

    async def main():
        dog = Watchdog(act, fast.actuator.watchdog_s, on_trip=trips.append)

        async def control_loop():
            act.engine_kill(False)
            act.throttle(0.5)
            act.brake(APPLY)
            while True:
                act.tick()
                await asyncio.sleep(0.005)

        dog_task = asyncio.create_task(dog.run())
        loop_task = asyncio.create_task(control_loop())
        await asyncio.sleep(0.1)
        assert not dog.tripped
        loop_task.cancel()  # the control loop dies with the brake applying
        for _ in range(100):
            await asyncio.sleep(0.01)
            if dog.tripped and act.released:
                break
        dog_task.cancel()
        return dog

    dog = asyncio.run(main())
    assert dog.tripped and trips and trips[0] > 0.05
    assert act.latched and act.engine_killed and act.throttle_fraction == 0.0
    assert act.released and factory.pin(rig.pins.brake_enable).state == 0
    act.close()
    assert_direction_never_switched_with_enable_on(factory.log, rig)


def test_hw_watchdog_thread_catches_blocked_event_loop(rig, factory, clock):
    act = GpioActuators(rig, pin_factory=factory, clock=clock)
    act.finish_release()
    act.engine_kill(False)
    dog = Watchdog(act, 0.5, clock=clock)
    act.tick()
    assert not dog.check()
    clock.advance(0.4)
    act.tick()
    clock.advance(0.4)
    assert not dog.check()  # 0.4 s since the last tick
    clock.advance(0.2)
    assert dog.check() and act.engine_killed
    # the thread variant starts and stops cleanly
    dog2 = Watchdog(act, 0.5, clock=clock)
    dog2.start_thread(period_s=0.01)
    dog2.stop_thread()
    act.close()


def test_hw_hardware_rig_composes_and_exits_safe(rig, factory, clock):
    from dyno.hw.rig import HardwareRig

    class Bus:
        closed = False

        def i2c_rdwr(self, *msgs):
            raise OSError(5, "nothing on this bus")

        def close(self):
            self.closed = True

    bus = Bus()
    with pytest.raises(ValueError):
        with HardwareRig(rig, pin_factory=factory, clock=clock, bus=bus, install_signals=False) as hw:
            assert hw.transport is not None and hw.thermometer is not None
            hw.actuators.finish_release()
            drive(hw.actuators, clock)
            raise ValueError("controller bug")
    assert bus.closed
    assert_safe_and_de_energised(factory, rig, hw.actuators)
