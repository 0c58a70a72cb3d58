"""``dyno doctor --sim``: the simulated rig as the doctor meets it, and the simulated operator.

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
    from dyno.hw.clock import FakeClock
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
