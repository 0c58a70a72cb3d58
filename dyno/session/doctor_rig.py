"""``dyno doctor``'s parts, composed here at the root: the real rig's, or (``--sim``) the simulated rig as the
doctor meets it, and the simulated operator (:func:`doctor_spec`).

One fake clock for the physics, the firmware and the Pi's output code (an 8 s release stroke, a few seconds of
data frames, take no wall time); the engine started and idling (the operator pulled the cord), so the primary
Hall channel turns; the operator, asked to turn a shaft that showed no edges, revs the idling engine with the
brake released (the CVT engages: the secondary turns) — nothing prompts.  ``--mock-pins``: the Pi's output code
on the wiring twin (:mod:`dyno.hw.mockpins`), whose reset pin resets the emulated firmware.  ``--drill
NAME[:ARG]``: a fault there from the start (no ``@T``): the sensors' (:data:`SENSOR_DRILLS`) on the physics,
the end switch's (:data:`TWIN_DRILLS`) on the twin.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass

from dyno.hw.doctor import DoctorSpec

SENSOR_DRILLS = ("hall-dead", "adc-stuck", "adc-error", "thermometer-lost")
TWIN_DRILLS = {"endswitch-stuck-closed": "stuck_closed", "endswitch-stuck-open": "stuck_open",
               "endswitch-bounce": "bounce"}
#: the throttle the simulated operator holds to turn the secondary (the CVT engages above ~2,100 rpm)
REV_THROTTLE = 0.4


@dataclass
class DoctorSim:
    sim: object
    clock: object
    pin_factory: object = None
    operator: object = None


class SimOperator:
    """Turns a shaft when the doctor asks: revs the idling engine (the brake is released) for the secondary."""

    def __init__(self, sim) -> None:
        self.sim = sim

    @contextmanager
    def turning(self, channel: str):
        wiring = self.sim.actuators.wiring
        if channel == "secondary":
            wiring.throttle(REV_THROTTLE)
        try:
            yield
        finally:
            wiring.throttle(0.0)


def parse_doctor_drill(text: str, cfg):
    """``NAME[:ARG]`` (no ``@T``) -> Drill; ConfigError naming ``--drill`` for anything else."""
    from dyno.session.drills import parse_drill
    from dyno.errors import ConfigError

    names = (*SENSOR_DRILLS, *TWIN_DRILLS)
    expected = f"NAME[:ARG] with NAME one of {', '.join(names)} (no @T: the fault is there from the start)"
    if "@" in text:
        raise ConfigError("command line", "--drill", f"{text!r}: {expected}")
    name = text.partition(":")[0].strip().lower()
    if name not in names:
        raise ConfigError("command line", "--drill", f"{text!r}: unknown for dyno doctor; {expected}")
    try:
        d = parse_drill(f"{text}@0")
    except ConfigError as exc:  # its argument: said without the run's @T
        raise ConfigError("command line", "--drill", str(exc.expected).replace("@0", "").replace("@T)", ")")) from None
    if d.arg == "input" and getattr(cfg, "input_torque", None) is None:
        raise ConfigError("command line", "--drill", f"{text}: the rig has no input torque channel (rig.toml "
                          "[input_torque], e.g. --rig hardware/rig-input-torque.toml)")
    if d.name in TWIN_DRILLS and cfg.pins.brake_released_input is None:
        raise ConfigError("command line", "--drill", f"{text}: the rig file declares no end-of-travel switch "
                          "(pins.brake_released_input in its [pins])")
    return d


def build(cfg, *, mock_pins: bool, drills=(), seed: int = 0, twin: bool | None = None) -> DoctorSim:
    """The doctor's simulated rig; ``twin`` (default: ``mock_pins``) builds the wiring twin even when the output
    checks do not run (the declared inputs are read through it)."""
    from dyno.clock import FakeClock
    from dyno.sim.rig import SimRig

    parsed = [parse_doctor_drill(t, cfg) for t in drills]
    if any(d.name in TWIN_DRILLS for d in parsed) and not mock_pins:
        from dyno.errors import ConfigError

        raise ConfigError("command line", "--drill", "the end-switch drills act through the wiring twin: add "
                          "--mock-pins")
    from dyno.session.input_channel import sim_params_for

    clock = FakeClock(start_s=0.0)
    sim = SimRig(clock.now, protocol=cfg.protocol, seed=seed, params=sim_params_for(None, cfg),
                 brake_hold_relay=cfg.actuator.brake_hold_relay,  # K3, and the air sensor: as the rig file says
                 bme280_address=cfg.ambient.address if cfg.ambient.sensor == "bme280" else None,
                 bme280_seed=0)  # (the doctor's chip error: seed 0's)
    out = DoctorSim(sim, clock, operator=SimOperator(sim))
    if mock_pins if twin is None else twin:
        from dyno.hw.mockpins import SimPinFactory

        out.pin_factory = SimPinFactory(cfg, sim.actuators, clock, armed=True,
                                        reset=lambda: sim.firmware.reset(clock.now()))
    for d in parsed:
        _apply(out, d)
    sim.start_engine()  # the operator pulls the cord: the engine idles
    return out


def _apply(ds: DoctorSim, d) -> None:
    m = ds.sim.model
    if d.name in TWIN_DRILLS:
        ds.pin_factory.end_switch_fault(TWIN_DRILLS[d.name])
    elif d.name == "hall-dead":
        m.stuck_hall.update(("primary", "secondary") if d.arg == "both" else (d.arg,))
    elif d.name == "adc-stuck":
        if d.arg == "input":
            m.input_stuck = True
        else:
            m.adc_stuck = True
    elif d.name == "adc-error":
        if d.arg == "input":
            m.input_error_prob = 1.0
        else:
            m.adc_error_prob = 1.0
    elif d.name == "thermometer-lost":
        ds.sim.bus.thermometer_lost = True


def doctor_spec(cfg, *, sim: bool = False, mock_pins: bool = False, drills=(), toggle: bool = False,
                transport_kind: str | None = None, interactive: bool = False) -> DoctorSpec:
    """The diagnosis of ``cfg``'s rig: the real one, or (``sim``) the simulated rig with the engine idling, the
    operator simulated and one fake clock (:func:`build`); ``mock_pins``: the output checks
    through the Pi's own code on the wiring twin; ``drills``: faults there from the start (``sim`` only);
    ``interactive``: a person at the terminal turns the rig for the data check."""
    if (mock_pins or drills) and not sim:
        from dyno.errors import ConfigError

        raise ConfigError("command line", "--mock-pins/--drill", "the wiring twin and the drills are for --sim")
    if not sim:
        operator = None
        if interactive:
            from dyno.hw.doctor_data import TerminalOperator

            operator = TerminalOperator()
        return DoctorSpec(cfg, toggle=toggle, transport_kind=transport_kind, operator=operator)
    ds = build(cfg, mock_pins=mock_pins, drills=list(drills), twin=mock_pins or _declares_inputs(cfg))
    clock, pin_factory, serial_port = ds.clock, ds.pin_factory, None
    if (transport_kind or cfg.transport) == "serial":  # opened as diagnose opens it: the Nano resets
        from dyno.sim.serial_port import SimSerialPort

        serial_port = SimSerialPort(ds.sim, clock)
    toggle = toggle or mock_pins  # --mock-pins: the output checks run (nothing moves but the simulation)
    if toggle and pin_factory is None:  # --sim --toggle alone: the twin as well (the reset pin wired)
        from dyno.hw.mockpins import SimPinFactory

        pin_factory = SimPinFactory(cfg, ds.sim.actuators, clock, armed=True,
                                    reset=lambda: ds.sim.firmware.reset(clock.now()))
    return DoctorSpec(cfg, toggle=toggle, transport_kind=transport_kind, bus=ds.sim.bus, serial_port=serial_port,
                      clock=clock, pin_factory=pin_factory, operator=ds.operator)


def _declares_inputs(cfg) -> bool:
    """The rig file declares an input the twin drives (the E-stop monitor, the end switch): the simulated
    doctor reads it through the twin even read-only."""
    return cfg.pins.estop_input is not None or cfg.pins.brake_released_input is not None
