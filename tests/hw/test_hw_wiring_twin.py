"""The Pi's output code against a twin of its wiring (issue 36): an end switch that lies, a held E-stop, a
signal inside a command, a watchdog whose own handling fails, a second E-stop.

The twin (:class:`dyno.hw.mockpins.SimPinFactory`) sits on a toy actuator here (a screw at constant speed,
end stops at 0 and 40 mm): the verdicts asserted are the toy's position, not what the driver says of itself.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import pytest

from dyno.control.outputs import APPLY, RELEASE, STOP
from dyno.errors import SafetyAbort
from dyno.clock import FakeClock
from dyno.hw.estop import EstopInput
from dyno.hw.mockpins import SimPinFactory
from dyno.hw.outputs import GpioActuators
from dyno.hw.safety import Watchdog

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

END_SWITCH_BCM, ESTOP_BCM = 27, 22
TRAVEL_MM = 40.0
FREE_TRAVEL_MM = 1.0


class ToyWiring:
    """The copper and a screw actuator: the enable moves it at constant speed in the relay's direction."""

    def __init__(self, clock, full_stroke_s: float) -> None:
        self.clock = clock
        self.speed_mm_s = TRAVEL_MM / full_stroke_s
        self.model = SimpleNamespace(actuator_mm=0.0, t_s=clock.now())
        self.dir = STOP
        self.ignition = False
        self.enable_on_at: list[tuple[float, int]] = []  # (t, direction) each time the actuator is powered

    def _sync(self) -> None:
        t = self.clock.now()
        dt, self.model.t_s = t - self.model.t_s, t
        if self.dir and dt > 0:
            self.model.actuator_mm = min(TRAVEL_MM, max(0.0, self.model.actuator_mm + self.dir * self.speed_mm_s * dt))

    def brake(self, direction: int) -> None:
        self._sync()
        if direction and direction != self.dir:
            self.enable_on_at.append((self.clock.now(), direction))
        self.dir = direction

    def relay(self, direction: int) -> None:
        self._sync()

    def throttle(self, fraction: float) -> None:
        pass

    def engine_kill(self, killed: bool) -> None:
        self.ignition = not killed

    @property
    def pads_off(self) -> bool:
        self._sync()
        return self.model.actuator_mm <= FREE_TRAVEL_MM


@pytest.fixture
def rig_wired(rig):
    """The test rig (2 s stroke) with both inputs declared and K3 not fitted: the driver's release is judged."""
    pins = dataclasses.replace(rig.pins, brake_released_input=END_SWITCH_BCM, estop_input=ESTOP_BCM)
    return dataclasses.replace(rig, pins=pins, actuator=dataclasses.replace(rig.actuator, brake_hold_relay=False))


def _build(rig, clock, mode=None):
    toy = ToyWiring(clock, rig.actuator.full_stroke_s)
    twin = SimPinFactory(rig, toy, clock)
    twin.end_switch_mode = mode
    act = GpioActuators(rig, pin_factory=twin, clock=clock)
    twin.arm()
    return toy, twin, act


def _apply(act, clock, s: float) -> None:
    act.step(APPLY, s)  # blocking: the FakeClock moves with its sleeps


def test_a_working_switch_confirms_a_release_from_a_known_position_in_the_travel_it_needs(rig_wired):
    clock = FakeClock()
    toy, twin, act = _build(rig_wired, clock)
    assert act.finish_release() and act.release_basis == "end_of_travel"  # start-up: the full stroke, the switch confirming
    _apply(act, clock, 0.4)  # 8 mm onto the rotor
    assert toy.model.actuator_mm == pytest.approx(8.0, abs=0.7)
    t0 = clock.now()
    act.safe_state(latch=True)
    assert act.finish_release()
    assert act.release_basis == "end_of_travel" and not act.faults
    assert toy.model.actuator_mm == 0.0 and toy.dir == STOP
    # the travel it needed (0.4 s back + the estimate's tolerance), not a full stroke from an assumed full apply
    assert clock.now() - t0 < 0.7 * rig_wired.actuator.full_stroke_s


@pytest.mark.parametrize("fault_at", ["applying", "held"])
def test_a_switch_stuck_closed_on_a_loaded_brake_is_a_fault_and_the_release_runs_its_full_stroke(rig_wired, fault_at):
    clock = FakeClock()
    toy, twin, act = _build(rig_wired, clock)
    act.finish_release()
    if fault_at == "applying":
        twin.end_switch_fault("stuck_closed")
        _apply(act, clock, 0.4)
    else:
        _apply(act, clock, 0.4)
        twin.end_switch_fault("stuck_closed")
        clock.advance(0.05)
        act.tick()
    assert [f["channel"] for f in act.faults] == ["end_switch"], act.faults
    assert "closed" in act.faults[0]["detail"]
    act.safe_state(latch=True)
    assert act.finish_release()
    # the physics: the pads are off (the old driver stopped at the first closed reading, 8 mm on the rotor)
    assert toy.pads_off and toy.model.actuator_mm == 0.0
    assert act.release_basis == "full_stroke_time"
    with pytest.raises(SafetyAbort, match="dyno doctor --toggle"):
        act.clear_latch()  # re-arm refused until the switch is checked


def test_a_switch_stuck_open_is_a_fault_named_after_the_full_stroke(rig_wired):
    clock = FakeClock()
    toy, twin, act = _build(rig_wired, clock, mode="stuck_open")
    assert act.finish_release()
    assert act.release_basis == "full_stroke_time"
    assert act.faults and "did not close" in act.faults[0]["detail"]
    assert act.output_states()["faults"][0]["channel"] == "end_switch"


def test_a_chattering_switch_is_caught_and_the_pads_still_leave_the_rotor(rig_wired):
    clock = FakeClock()
    toy, twin, act = _build(rig_wired, clock)
    act.finish_release()
    twin.end_switch_fault("bounce")
    for _ in range(10):  # a hold plan's pulses: apply a little, read the switch at every tick
        _apply(act, clock, 0.1)
        for _ in range(10):
            clock.advance(0.02)
            act.tick()
    assert act.faults, "a loose contact closing at 20 mm went unnoticed"
    act.safe_state(latch=True)
    assert act.finish_release() and toy.model.actuator_mm == 0.0


def test_a_held_estop_gives_one_release_stroke_then_nothing(rig_wired):
    """E-stop held 30 s, the watchdog looking at its level every 25 ms: one stroke, the actuator then off
    (the old driver restarted the stroke at every look: the enable stayed on for the whole hold)."""
    clock = FakeClock()
    toy, twin, act = _build(rig_wired, clock)
    act.finish_release()
    estop = EstopInput(ESTOP_BCM, act, pin_factory=twin)
    stops = []
    estop.on_open.append(stops.append)
    wd = Watchdog(act, 0.5, clock=clock)
    wd.level_checks.append(estop.poll)
    _apply(act, clock, 0.4)
    n_on = len(toy.enable_on_at)
    twin.open_estop()
    assert not toy.ignition and act.latched
    for _ in range(int(30 / wd.period_s)):
        clock.advance(wd.period_s)
        act.tick()  # the control loop, alive
        wd.kick()
        wd.step()
    assert toy.model.actuator_mm == 0.0 and toy.dir == STOP
    assert toy.enable_on_at[n_on:] == [(pytest.approx(toy.enable_on_at[n_on][0]), RELEASE)]  # one stroke
    assert act.release_basis == "end_of_travel" and len(stops) == 1
    twin.close_estop()
    wd.step()
    assert not estop.tripped
    act.clear_latch()  # re-armed
    twin.open_estop()  # a second E-stop after the re-arm is a stop of its own
    assert len(stops) == 2 and estop.openings == 2 and act.latched
    estop.close()


def test_a_signal_inside_a_command_cannot_let_the_command_through_after_the_latch(rig_wired):
    """The handler (the rig path's: safe state, latched) runs inside ``brake(APPLY)``, between its latch check
    and its writes.  From the latch on, the actuator is never powered toward the rotor."""
    from dyno.session.safety import LoopTimeClock

    fake = FakeClock()
    clock = LoopTimeClock(fake.now)
    toy, twin, act = _build(rig_wired, clock)
    while not act.released:
        fake.advance(0.01)
        act.tick()
    latched_at = []

    def handler() -> None:  # what dyno's SIGINT handler does on the rig path
        import sys

        if sys._getframe(2).f_code.co_name == "_command":
            clock.on_now = None
            act.safe_state(latch=True)
            latched_at.append(len(toy.enable_on_at))

    clock.on_now = handler
    act.brake(APPLY)
    assert latched_at and act.latched
    for _ in range(100):
        fake.advance(0.01)
        act.tick()
    assert all(d == RELEASE for _, d in toy.enable_on_at[latched_at[0]:]), toy.enable_on_at
    assert toy.model.actuator_mm == 0.0 and toy.dir == STOP
    assert act.output_states()["brake_actuator"] == "stopped"


def test_the_watchdog_survives_an_exception_in_its_own_handling(rig_wired):
    clock = FakeClock()
    toy, twin, act = _build(rig_wired, clock)
    assert act.finish_release()  # the start-up release's full stroke (no apply before it)
    _apply(act, clock, 0.4)

    class Unwritable:
        def error(self, *a, **k):
            raise OSError(28, "No space left on device")

    def broken():
        raise OSError(5, "Input/output error")

    wd = Watchdog(act, 0.5, clock=clock)
    wd.log = Unwritable()
    wd.level_checks.append(broken)
    real_safe = act.safe_state
    calls = {"n": 0}

    def flaky_safe(latch=False):  # the fallback itself fails once
        calls["n"] += 1
        if calls["n"] == 1:
            raise RuntimeError("safe state failed")
        real_safe(latch=latch)

    act.safe_state = flaky_safe
    for _ in range(200):
        clock.advance(wd.period_s)
        wd.kick()
        wd.step()  # never raises
    assert wd.tripped and calls["n"] > 1
    assert wd.errors == ["watchdog look failed: OSError: [Errno 5] Input/output error; safe state failed too: "
                         "RuntimeError"] or len(wd.errors) <= 2, wd.errors
    assert toy.model.actuator_mm == 0.0 and not toy.ignition


def test_clear_latch_refuses_while_the_release_runs(rig_wired):
    clock = FakeClock()
    toy, twin, act = _build(rig_wired, clock)
    act.finish_release()
    _apply(act, clock, 0.4)
    act.safe_state(latch=True)
    with pytest.raises(SafetyAbort, match="still running"):
        act.clear_latch()
    act.brake(STOP)  # refused while latched: the release runs on
    assert act.finish_release() and toy.pads_off
    act.clear_latch()
    assert not act.latched


def test_a_switch_fault_outlives_the_process_until_doctor_passes(rig_wired, tmp_path, monkeypatch):
    """Found stuck in one session, the switch is not trusted by the next (a new driver would have forgotten):
    releases run their full stroke and the re-arm is refused until ``dyno doctor --toggle``'s switch check passes."""
    from dyno.hw.doctor_report import Report
    from dyno.hw.doctor_switch import check_end_switch
    from dyno.hw import rig_faults
    from dyno.hw.rig import HardwareRig

    monkeypatch.setenv("DYNO_STATE_DIR", str(tmp_path))

    class Bus:
        def i2c_rdwr(self, *msgs):
            raise OSError(5, "no Nano here")

        def close(self):
            pass

    clock = FakeClock()
    toy = ToyWiring(clock, rig_wired.actuator.full_stroke_s)
    twin = SimPinFactory(rig_wired, toy, clock, armed=True)
    with HardwareRig(rig_wired, pin_factory=twin, clock=clock, bus=Bus(), install_signals=False,
                     persist_faults=True) as hw:
        hw.actuators.finish_release()
        twin.end_switch_fault("stuck_closed")
        _apply(hw.actuators, clock, 0.4)
        assert hw.actuators.faults
    assert [f["channel"] for f in rig_faults.load()] == ["end_switch"]
    twin.end_switch_fault(None)  # the wire repaired; the next session does not know that yet
    twin2 = SimPinFactory(rig_wired, toy, clock, armed=True)
    with HardwareRig(rig_wired, pin_factory=twin2, clock=clock, bus=Bus(), install_signals=False,
                     persist_faults=True) as hw:
        act = hw.actuators
        assert act.faults and act.faults[0]["inherited"]
        assert act.finish_release() and act.release_basis == "full_stroke_time"  # the switch not trusted
        assert "dyno doctor --toggle" in act.rearm_refusal()
        report = Report()
        check_end_switch(report, rig_wired, act, "closed", "open", "closed", persisted=True)
        assert report.ok and "cleared" in report.checks[-1].detail
    assert rig_faults.load() == []


def test_the_nano_reset_wait_keeps_the_watchdog_fed(rig_wired, factory):
    """``dyno doctor --toggle`` pulses RESET and waits 1.25 s for the bootloader: longer than the watchdog's
    0.5 s.  The wait is the control loop while it runs (it used to sleep silently: the watchdog thread tripped
    and the brake step that followed was refused, "the watchdog tripped during the step")."""
    from dyno.clock import MonotonicClock

    act = GpioActuators(rig_wired, pin_factory=factory, clock=MonotonicClock())
    wd = Watchdog(act, 0.2, clock=MonotonicClock())
    wd.start_thread()
    try:
        act.reset_arduino()
    finally:
        wd.stop_thread()
        act.close()
    assert not wd.tripped
