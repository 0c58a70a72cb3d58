"""The calibration wizard's rig (``dyno calibrate``): a poller on the simulated fixture or the real rig, with
the same link and sensor safety as a test.  Composition, split from :mod:`dyno.session.root` (whose ``open_rig`` it
uses); nothing below the faces imports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from dyno.acquisition.poller import Poller
from dyno.acquisition.reader import make_reader
from dyno.session.root import open_rig


@dataclass
class CalibrationContext:
    """What ``dyno calibrate`` acquires from, with the same safety as a test.

    ``sim`` is the simulated fixture (:class:`dyno.sim.ui_fixture.FixtureRig`) or None;
    ``hw`` the real rig (:class:`dyno.hw.rig.HardwareRig`) or None.  Nothing moves in a
    calibration (the secondary is locked by hand), so the safety here is the link and the
    torque sensor: a trip ends the calibration (``on_trip``) and keeps the outputs safe.
    """

    poller: Poller
    sim: object = None
    hw: object = None
    monitor: object = None
    watchdog: object = None
    drills: object = None
    trip: object = None  # the first dyno.control.safety.Trip
    controller: object = None  # (none: drills that need one are refused for calibration)
    writer: object = None
    twin: object = None  # --mock-pins: the wiring twin (dyno.hw.mockpins) over the fixture's actuator
    rig_cfg: object = None
    closed: bool = False  # close_calibration ran (the rig released)


def build_calibration(*, sim: bool, loop, seed: int = 0, speed: float = 1.0, rig_path=None,
                      fixture_kw: dict | None = None, drills=(), on_trip=None,
                      mock_pins: bool = False, firmware_elf=None) -> CalibrationContext:
    from dyno.control.safety import SafetyLimits, SafetyMonitor
    from dyno.rig.config import load_rig

    rig_cfg = load_rig(rig_path)
    from dyno.transports.budget import check_budget

    rig_cfg = check_budget(rig_cfg)  # the same link budget as a run: derated to fit, or refused
    want_input = getattr(rig_cfg, "input_torque", None) is not None  # asked for as in a run
    hw = twin = None
    if sim:
        from dyno.sim.ui_fixture import build_fixture_poller

        t0 = loop.time()

        def sim_now() -> float:
            return (loop.time() - t0) * speed

        # the simulated rig has the engine-side channel when rig.toml declares it (as in a run); asked for as
        # on the rig (a fixture without it: announced absent); paced: each real-time poll spans `speed` x more
        fixture_kw = {"input_fitted": want_input, **(fixture_kw or {})}
        if firmware_elf is not None:  # the Nano's own ELF in simavr, on the rig file's link
            from dyno.sim.elf_firmware import elf_spec

            fixture_kw["firmware_elf"] = elf_spec(firmware_elf, rig_cfg, rig_cfg.protocol)
        fixture, poller = build_fixture_poller(sim_now, seed=seed, poll_hz=rig_cfg.poll_hz, pace=speed,
                                               want_input=want_input or None, **fixture_kw)
        if mock_pins:  # the Pi's own output code (HardwareRig) over the wiring twin and the fixture's actuator
            hw, twin = _twin_rig(rig_cfg, fixture, sim_now, speed)
    else:
        fixture, sim_now = None, None
        hw = open_rig(rig_cfg)
        try:  # (the engine-side converter asked for as a run does)
            reader = make_reader(rig_cfg.protocol, hw.transport, want_input=want_input)
            poller = Poller(reader, poll_hz=rig_cfg.poll_hz, blocking_io=True)
        except BaseException:
            hw.__exit__(None, None, None)
            raise
    if hw is not None:  # nothing else runs the rig's outputs here: the watchdog thread, and the polls tick
        hw.watchdog.start_thread()  # them (the start-up release stroke ends and de-energises on time)
    lim = rig_cfg.limits
    runner = None
    if drills:  # armed below, from the first frame
        from dyno.session.drills import DrillRunner

        runner = DrillRunner(drills, loop, sim_now=sim_now, speed=speed)
    ctx = CalibrationContext(poller, sim=fixture, hw=hw, twin=twin, watchdog=hw.watchdog if hw is not None else None,
                             rig_cfg=rig_cfg, drills=runner, monitor=SafetyMonitor(SafetyLimits(comms_timeout_s=lim.comms_timeout_s),
                                                                    poller))

    def check(events, now_s: float) -> None:
        if ctx.hw is not None:
            ctx.hw.actuators.tick()
        if ctx.watchdog is not None:
            ctx.watchdog.kick()
        if ctx.trip is not None:
            return
        trip = ctx.monitor.check(now_s, loaded=False)
        if trip is not None:
            ctx.trip = trip
            if ctx.hw is not None:
                from dyno.control.outputs import enter_safe_state

                enter_safe_state(ctx.hw.actuators, latch=True)
            if on_trip is not None:
                on_trip(trip)

    poller.listeners.append(check)
    if ctx.drills is not None:
        ctx.drills.arm_from_first_frame(ctx)
    return ctx


def _twin_rig(rig_cfg, fixture, sim_now, speed: float):
    """``--mock-pins``: :class:`dyno.hw.rig.HardwareRig` on the wiring twin, the fixture's actuator behind it;
    its clock is the fixture's (paced: a blocking wait sleeps the real time it stands for)."""
    import time

    from dyno.session.safety import LoopTimeClock
    from dyno.hw.mockpins import SimPinFactory
    from dyno.hw.rig import HardwareRig
    from dyno.sim.fixture_actuator import FixtureActuatorWiring

    clock = LoopTimeClock(sim_now, sleep=lambda dt_s: time.sleep(max(0.0, dt_s) / speed))
    wiring = FixtureActuatorWiring(sim_now)
    twin = SimPinFactory(rig_cfg, wiring, clock, armed=True, reset=lambda: fixture.firmware.reset(sim_now()))
    hw = HardwareRig(rig_cfg, pin_factory=twin, clock=clock, bus=fixture.bus, install_signals=False,
                     persist_faults=False)
    return hw.__enter__(), twin


def close_calibration(ctx: CalibrationContext) -> None:
    if ctx.drills is not None:
        ctx.drills.cancel()
    if ctx.closed:
        return
    if ctx.hw is not None:
        ctx.closed = True
        ctx.hw.__exit__(None, None, None)
    if ctx.sim is not None:
        ctx.closed = True
        ctx.sim.close()  # (--firmware-elf: the simavr harness ends with the calibration)
