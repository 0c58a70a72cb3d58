"""A fake rig for the engine and the plans: milliseconds, not the 150 Hz simulation (a test double, in the
package as gpiozero's MockFactory and python-can's virtual bus are: tests/control/test_fake_rig.py).

The real engine (:class:`dyno.control.controller.TestController`, its state table, its gate on the
outputs, its measuring windows, its last word) runs on a :class:`~dyno.clock.VirtualTimeLoop` over

* :class:`FakePlant` — a deliberately crude, deterministic world of its own (not the simulator's
  physics, not the host's maps): the brake's position integrates the actuator's command, the engine
  follows throttle and ignition at once, the secondary slows as the brake loads it, the brake torque
  grows with the pads' travel past their free travel;
* :class:`FakePoller` — the poller's public face (``listeners``, ``streams``, ``rpm``,
  ``device_now_us``, ``disturbances_between``, the link's times), filling the real
  :class:`~dyno.acquisition.streams.Streams` with one Hall edge per revolution and the strain gauge's
  conversions at 125 Hz;
* :class:`FakeActuators` — the :class:`~dyno.control.outputs.Actuators` protocol, recording every
  command (``log``) and driving the plant.

A plan therefore runs through the real :class:`~dyno.control.engine.EngineContext`; a test reads the
plant's truth and the actuators' record, not what the engine reports about itself.
"""

from __future__ import annotations

import asyncio
import math

from dyno.acquisition.streams import Streams
from dyno.analysis.calibration_history import CalibrationEntry
from dyno.analysis.engine_map import load_engine_map
from dyno.clock import VirtualTimeLoop
from dyno.control.api import TestPlan
from dyno.control.controller import TestController
from dyno.control.outputs import APPLY, RELEASE, STOP
from dyno.control.safety import SafetyLimits
from dyno.protocol import v1
from dyno.protocol.v1 import Event

SLOPE_COUNTS_PER_NM = 800.0
INTERCEPT_COUNTS = 8000.0


class FakePlant:
    """The fake world (module doc).  Speeds in rpm, brake position 0 (released) .. 1 (full apply)."""

    full_stroke_s = 4.0
    free_travel = 0.05  # the pads touch the rotor past this

    def __init__(self) -> None:
        self.brake_pos = 0.6  # unknown to the host at the start: the engine's first release must clear it
        self.brake_dir = STOP
        self.throttle = 0.0
        self.ignition = False
        self.engine_started = False
        self.rpm_primary = 0.0
        self.rpm_secondary = 0.0
        self.governor_failed = False  # a fault a test may inject: the engine runs away (over-speed)

    def start_engine(self) -> None:
        self.engine_started = True

    @property
    def brake_torque_nm(self) -> float:
        return 40.0 * max(0.0, self.brake_pos - self.free_travel) if self.rpm_secondary > 0 else 0.0

    @property
    def pads_off(self) -> bool:
        return self.brake_pos <= self.free_travel

    def step(self, dt_s: float) -> None:
        self.brake_pos = min(1.0, max(0.0, self.brake_pos + self.brake_dir * dt_s / self.full_stroke_s))
        running = self.ignition and self.engine_started
        target = (1700.0 + 1900.0 * self.throttle - 500.0 * max(0.0, self.brake_pos - self.free_travel)
                  + 3000.0 * self.governor_failed if running else 0.0)
        rate = 4000.0 * dt_s  # rpm the engine can change in dt
        self.rpm_primary += max(-rate, min(rate, target - self.rpm_primary))
        if not running and self.rpm_primary < 300.0:
            self.rpm_primary = 0.0
        if self.rpm_primary >= 2000.0:  # engaged: the belt sets the secondary (heavier load, lower ratio)
            self.rpm_secondary = self.rpm_primary / (0.75 + 2.0 * max(0.0, self.brake_pos - self.free_travel))
        else:  # below engagement the driven side coasts down on its drag and the brake
            self.rpm_secondary = max(0.0, self.rpm_secondary - (400.0 + 4000.0 * self.brake_pos) * dt_s)


class FakeActuators:
    """The Actuators protocol over the plant, recording each command as ``(t_s, what, value)``."""

    brake_full_stroke_s = FakePlant.full_stroke_s

    def __init__(self, plant: FakePlant, now) -> None:
        self.plant, self._now = plant, now
        self.log: list[tuple[float, str, object]] = []
        self.latched = False

    def _record(self, what: str, value) -> None:
        self.log.append((self._now(), what, value))

    def brake(self, direction: int) -> None:
        if self.latched and direction == APPLY:
            self._record("refused", "brake apply")
            return
        self._record("brake", direction)
        self.plant.brake_dir = direction

    def throttle(self, fraction: float) -> None:
        if self.latched and fraction > 0:
            self._record("refused", "throttle")
            return
        self._record("throttle", fraction)
        self.plant.throttle = fraction

    def engine_kill(self, killed: bool) -> None:
        if self.latched and not killed:
            self._record("refused", "engine run")
            return
        self._record("engine_kill", killed)
        self.plant.ignition = not killed

    def safe_state(self, latch: bool = False) -> None:
        self._record("safe_state", latch)
        self.latched = self.latched or latch
        self.plant.throttle, self.plant.ignition, self.plant.brake_dir = 0.0, False, RELEASE

    def tick(self, now_s: float) -> None:
        if self.plant.brake_dir == RELEASE and self.plant.brake_pos <= 0.0:
            self.plant.brake_dir = STOP  # the release stroke ends de-energised

    def clear_latch(self) -> None:
        self.latched = False

    def commands(self, what: str) -> list:
        return [v for _, w, v in self.log if w == what]


class FakePoller:
    """The poller's public face over the plant (module doc)."""

    poll_period_s = 1.0 / 100.0
    thermometer = None
    rotor_temp_c = math.nan
    rotor_temp_time_s = math.nan
    epoch_start_us = None

    def __init__(self, plant: FakePlant, loop: asyncio.AbstractEventLoop) -> None:
        self.plant, self.loop = plant, loop
        self.listeners: list = []
        self.streams = Streams()
        self.t_us = 0
        self._phase = {v1.CH_PRIMARY: 0.0, v1.CH_SECONDARY: 0.0}
        self._adc_next_us = 0
        self._adc_n = 0
        self.started_s = self.last_valid_frame_s = self.last_poll_s = None
        self.polls = 0

    def set_poll_hz(self, hz) -> None:  # (the engine's idle rate while waiting: the fake polls at one rate)
        pass

    def device_now_us(self):
        return self.t_us if self.polls else None

    def rpm(self, channel: int) -> float:
        e = self.streams.edges[channel]
        if len(e) < 2 or self.t_us - e[-1] > 2 * (e[-1] - e[-2]) + 50_000:
            return 0.0
        return 60e6 / (e[-1] - e[-2])

    def disturbances_between(self, t0_s: float, t1_s: float) -> list:
        return []

    def poll(self) -> None:
        """One poll: the plant advanced by a poll period, its events into the streams, the listeners told."""
        dt_s = self.poll_period_s
        t0 = self.t_us
        self.plant.step(dt_s)
        self.t_us = t1 = t0 + int(dt_s * 1e6)
        events = []
        for ch, rpm in ((v1.CH_PRIMARY, self.plant.rpm_primary), (v1.CH_SECONDARY, self.plant.rpm_secondary)):
            revs = self._phase[ch] + rpm / 60.0 * dt_s
            n = int(revs)
            for k in range(n):  # the edges evenly in the period, one per revolution
                frac = (k + 1 - self._phase[ch]) / max(revs - self._phase[ch], 1e-12)
                events.append(Event(ch, t0 + int(frac * (t1 - t0)), int(rpm)))
            self._phase[ch] = revs - n
        while self._adc_next_us <= t1:
            self._adc_n += 1
            code = INTERCEPT_COUNTS + SLOPE_COUNTS_PER_NM * self.plant.brake_torque_nm + (self._adc_n % 3) - 1
            events.append(Event(v1.CH_ADC, self._adc_next_us, int(round(code))))
            self._adc_next_us += 8000  # 125 Hz
        events.sort(key=lambda e: e.t_us)
        self.streams.extend(events)
        now = self.loop.time()
        self.polls += 1
        self.started_s = self.started_s if self.started_s is not None else now
        self.last_valid_frame_s = self.last_poll_s = now
        for fn in list(self.listeners):
            fn(events, now)


def calibration() -> CalibrationEntry:
    return CalibrationEntry(date="2026-01-01", slope_counts_per_nm=SLOPE_COUNTS_PER_NM,
                            intercept_counts=INTERCEPT_COUNTS, r2=1.0, n_samples=0, note="the fake rig's gauge")


def engine_map():
    from dyno.resources import DEFAULT_ENGINE_MAP  # (the points' input power; the fake plant does not use it)

    return load_engine_map(DEFAULT_ENGINE_MAP)


class FakeRig:
    """The fake rig, the real engine over it, on a virtual-time loop: ``run(plan)`` runs a test to its end."""

    def __init__(self, plan: TestPlan = TestPlan(), *, runner_for=None, from_idle=None,
                 limits: SafetyLimits | None = None) -> None:
        self.loop = VirtualTimeLoop()
        self.plant = FakePlant()
        self.poller = FakePoller(self.plant, self.loop)
        self.act = FakeActuators(self.plant, self.loop.time)
        self.states: list[str] = []
        asyncio.set_event_loop(self.loop)
        self.controller = TestController(
            self.poller, self.act, calibration(), engine_map(), plan=plan,
            limits=limits or SafetyLimits(), auto_go=True, on_wait_engine=self.plant.start_engine,
            runner_for=runner_for, from_idle=from_idle)
        self.controller.listeners.append(lambda c: self.states.append(c.state.value))

    def run(self, timeout_s: float = 600.0):
        async def main():
            ticker = self.loop.create_task(self._poll_forever())
            try:
                return await asyncio.wait_for(self.controller.run(), timeout_s)
            finally:
                # after the test the polls go on a little: the release stroke ends on the engine's ticks
                await asyncio.sleep(self.plant.full_stroke_s + 0.5)
                ticker.cancel()

        try:
            return self.loop.run_until_complete(main())
        finally:
            asyncio.set_event_loop(None)
            self.loop.close()

    async def _poll_forever(self) -> None:
        while True:
            await asyncio.sleep(self.poller.poll_period_s)
            self.poller.poll()
