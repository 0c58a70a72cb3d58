"""The rig description: ``hardware/rig.toml`` loaded into frozen dataclasses.

Everything that differs between one physical dynamometer and another (pin
map, bus addresses, serial port, gear ratio, Hall debounce windows, limits,
actuator timing, throttle servo end points) lives in one TOML file, validated
on load so a typo stops the program before it touches a pin.  Every quantity
carries its unit in its key.

:func:`rig_from_dict` validates a parsed mapping; :func:`load_rig` is the only
function that touches a file.  Bad input raises
:class:`dyno.errors.ConfigError` naming the file, the dotted field and what
was expected (the CLI prints it on one line and exits 2).

Pins are Broadcom (BCM) GPIO numbers as gpiozero uses them.  ``"BOARD33"``
(physical header pin, the numbering of the thesis code, Messick 2018 App. H)
and ``"GPIO13"`` are accepted too and converted, because copying pin numbers
off the thesis PCB silkscreen is exactly the mistake this file should catch.
"""

from __future__ import annotations

import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from dyno.rig.reader import REQUIRED, FieldReader
from dyno.errors import ConfigError
from dyno.rig.ambient import AmbientConfig, ambient_table
from dyno.rig.driveline import DrivelineConfig, driveline_table
from dyno.rig.input_torque import InputTorqueConfig, input_torque_table
from dyno.rig.inertia import DRIVEN_INERTIA_KEYS, InertiaConfig, inertia_table
from dyno.rig.locate import find_rig, packaged_rig, require_own_rig

SCHEMA = "dyno.rig/1"

#: The shipped rig description (the package's, :mod:`dyno.resources`); which file a command reads is
#: :func:`dyno.rig.locate.find_rig` (``--rig``, ``$DYNO_RIG``, ./hardware, ~/.config/dyno, /etc/dyno, this).
DEFAULT_RIG_PATH = packaged_rig()

# 40-pin header: physical pin -> BCM GPIO (power/ground pins are absent).
_BOARD_TO_BCM = {
    3: 2, 5: 3, 7: 4, 8: 14, 10: 15, 11: 17, 12: 18, 13: 27, 15: 22, 16: 23, 18: 24,
    19: 10, 21: 9, 22: 25, 23: 11, 24: 8, 26: 7, 27: 0, 28: 1, 29: 5, 31: 6, 32: 12,
    33: 13, 35: 19, 36: 16, 37: 26, 38: 20, 40: 21,
}
# BCM 0/1 are the HAT ID EEPROM bus and 2/3 are I2C1 (SDA/SCL, with 1k8
# pull-ups on the board): an output there would fight the bus we poll.
RESERVED_BCM = {0: "HAT ID EEPROM (ID_SD)", 1: "HAT ID EEPROM (ID_SC)",
                2: "I2C1 SDA", 3: "I2C1 SCL"}
OUTPUT_BCM = range(4, 28)
BOOT_PULL_UP_BCM = range(4, 9)  # default pulls until a program claims the pin

PIN_NAMES = ("brake_enable", "brake_direction", "throttle_servo", "engine_kill", "arduino_reset")
OPTIONAL_INPUTS = ("estop_input", "brake_released_input")  # pins read, each optional
# Hardware PWM channels on the header; the throttle servo jitters on software PWM.
HARDWARE_PWM_BCM = {12, 13, 18, 19}

I2C_ADDRESS_MIN, I2C_ADDRESS_MAX = 0x03, 0x77  # 7-bit, outside the reserved ranges


@dataclass(frozen=True)
class Pins:
    """BCM GPIO numbers of the rig's outputs."""

    brake_enable: int  # MOSFET gate: high powers the brake actuator
    brake_direction: int  # DPDT relay: energised = APPLY (extend), off = RELEASE
    throttle_servo: int  # 50 Hz servo PWM
    engine_kill: int  # ignition kill relay
    arduino_reset: int  # drives the Nano's RESET through a transistor
    # Optional input: the E-stop chain's monitor contact, normally closed to ground (pull-up
    # on): open = STOP, so a pressed button, a cut wire or a lost connector all stop the rig.
    estop_input: int | None = None
    # Optional input: an end-of-travel switch closed (to ground, pull-up on) when the brake actuator is
    # fully retracted. Where declared, "released" is this switch closing; without it, a release stroke
    # that ran its full time uninterrupted (GpioActuators.release_basis).
    brake_released_input: int | None = None

    def as_dict(self) -> dict[str, int]:
        return {name: getattr(self, name) for name in PIN_NAMES}


@dataclass(frozen=True)
class I2CConfig:
    bus: int  # /dev/i2c-<bus>
    firmware_address: int  # the Nano (0x03)
    thermometer_address: int  # MLX90614 (0x5A)
    bus_speed_hz: int  # must match dtparam=i2c_arm_baudrate in /boot/config.txt
    retries: int = 3  # extra attempts per poll before it counts as a failure
    retry_backoff_s: float = 0.002  # first back-off; doubles per retry
    reset_after_failures: int = 20  # consecutive failed polls before pulsing RESET


@dataclass(frozen=True)
class SerialConfig:
    port: str
    baud: int
    timeout_s: float = 0.05  # one poll's answer at 115200 Bd takes < 4 ms
    boot_timeout_s: float = 3.0  # opening the port resets the Nano (DTR): wait this long for its first answer


@dataclass(frozen=True)
class Gear:
    """Chain/belt drive from the CVT secondary to the brake rotor."""

    secondary_sprocket_teeth: int
    brake_sprocket_teeth: int

    @property
    def ratio_brake_per_secondary(self) -> float:
        """Brake-rotor rpm per secondary rpm (32/61 on the thesis rig)."""
        return self.secondary_sprocket_teeth / self.brake_sprocket_teeth


@dataclass(frozen=True)
class Limits:
    rotor_temp_max_c: float
    overspeed_primary_rpm: float
    overspeed_secondary_rpm: float
    comms_timeout_s: float
    # the Nano's run-enable (issue 37): no valid poll for this long -> its output drops (engine cut, K3
    # releases the brake); sent with the over-speed limits at every boot; 0: never armed (docs/safety.md)
    supervisor_timeout_s: float = 0.2


@dataclass(frozen=True)
class ActuatorConfig:
    step_s: float  # default brake step the controller asks for
    full_stroke_s: float  # end stop to end stop at rated load
    relay_settle_s: float = 0.03  # direction relay contact bounce + release time
    watchdog_s: float = 0.5  # control loop silent this long -> safe state
    # K3, the "brake hold" relay (hardware/README.md): coil beside the kill relay's, NC contacts power the
    # actuator in release whenever the ignition is killed, with no software involved.
    brake_hold_relay: bool = False


@dataclass(frozen=True)
class ThrottleConfig:
    """Servo end points as pulse widths (thesis: 11 % / 4 % duty at 50 Hz)."""

    idle_pulse_us: float
    full_pulse_us: float
    frame_us: float = 20000.0  # 50 Hz servo frame

    def pulse_us(self, fraction: float) -> float:
        """Pulse width for a throttle fraction, clamped to 0..1."""
        f = min(1.0, max(0.0, float(fraction)))
        return self.idle_pulse_us + f * (self.full_pulse_us - self.idle_pulse_us)


@dataclass(frozen=True)
class ResetConfig:
    pulse_s: float = 0.25  # thesis value; the Nano needs > 2.5 us, relay/RC margin
    boot_s: float = 1.0  # optiboot waits ~0.5-1 s before the sketch runs
    active_high: bool = True  # pin high -> transistor pulls RESET low


@dataclass(frozen=True)
class DrivenConfig:  # the driven side's measured loss (its inertia: [inertia]'s driven_kg_m2)
    loss_file: str | None = None  # driven_loss.json of a coast-down: added back to efficiency when asked


@dataclass(frozen=True)
class TorqueZeroConfig:
    """Torque-channel zero read at rest before GO and after the last point."""

    read_s: float = 4.0  # averaging window at rest (4 s: 95 % half-width ~0.09 N m with the sim's noise)
    drift_max_nm: float = 0.15  # |after - before| beyond this (secondary N m) is flagged in the run and report
    correct: bool = False  # linear drift correction of the points' torque (extra keys; raw points unchanged)
    tare: bool = True  # the zero read before GO is the points' zero (the bridge offset moves between calibrations)


@dataclass(frozen=True)
class UncertaintyConfig:
    """Systematic uncertainties stated beside each point's CI (dyno/analysis/systematic.py)."""

    engine_map_rel: float = 0.10  # engine map torque, relative standard uncertainty, a map stating none (u95_terms)


@dataclass(frozen=True)
class ControlConfig:
    """Load-control gains (docs/control.md has the identification procedure).

    Each ``kp_*`` is actuator speed (fraction of full speed) per unit relative error; ``lead_*_s`` the
    position term's lead (``u = kp·(e + lead·de/dt)``); ``ff_*_s`` is the full-speed travel (s) given at
    once per unit relative setpoint change (feed-forward)."""

    kp_speed: float = 12.0
    lead_speed_s: float = 0.5
    ff_speed_s: float = 0.0
    kp_engine: float = 3.0
    lead_engine_s: float = 0.0
    kp_torque: float = 1.0
    deadband_rel: float = 0.004
    period_s: float = 0.05
    min_pulse_s: float = 0.02


@dataclass(frozen=True)
class RigConfig:
    path: str
    protocol: str  # "v2" | "v1" | "v0"
    transport: str  # "i2c" | "serial"
    poll_hz: float
    debounce_primary_us: int
    debounce_secondary_us: int
    kill_relay: str  # "energise_to_run" (fail-safe) | "energise_to_kill" (thesis PCB)
    pins: Pins
    i2c: I2CConfig
    serial: SerialConfig
    gear: Gear
    limits: Limits
    actuator: ActuatorConfig
    throttle: ThrottleConfig
    reset: ResetConfig
    driven: DrivenConfig = DrivenConfig()
    torque_zero: TorqueZeroConfig = TorqueZeroConfig()
    inertia: InertiaConfig = InertiaConfig()
    control: ControlConfig = ControlConfig()
    uncertainty: UncertaintyConfig = UncertaintyConfig()
    ambient: AmbientConfig = AmbientConfig()
    driveline: DrivelineConfig = DrivelineConfig()  # [driveline]: the loss between the CVT and the gauge
    input_torque: InputTorqueConfig | None = None  # [input_torque]: the engine-side channel (dyno.rig.input_torque)
    deprecations: tuple = ()  # one line each: an old key that was mapped (load_rig warns once per process)
    derate: bool = True  # polls that do not fit the link: poll_hz lowered to fit (said), else refused
    derated_from_hz: float | None = None  # the file's poll_hz, when derated to fit (dyno.transports.budget)

    @property
    def gear_ratio_brake_per_secondary(self) -> float:
        return self.gear.ratio_brake_per_secondary

    @property
    def poll_period_s(self) -> float:
        return 1.0 / self.poll_hz


# --------------------------------------------------------------------------- validation


class _Reader(FieldReader):
    """rig.toml's fields: the generic typed reader, plus the Raspberry Pi's pins."""

    def pin(self, data: Mapping, key: str) -> int:
        fld, v, _ = self._get(data, key, "pins.", REQUIRED)
        raw = v
        if isinstance(v, str):
            s = v.strip().upper()
            prefix = next((x for x in ("BOARD", "GPIO", "BCM") if s.startswith(x)), None)
            if prefix is None or not s[len(prefix):].isdigit():
                raise self.err(fld, f"unknown pin {raw!r}: expected a BCM number, 'GPIOn' or 'BOARDn'")
            n = int(s[len(prefix):])
            if prefix == "BOARD":
                if n not in _BOARD_TO_BCM:
                    raise self.err(fld, f"unknown pin {raw!r}: header pin {n} is not a GPIO")
                n = _BOARD_TO_BCM[n]
            v = n
        elif isinstance(v, bool) or not isinstance(v, int):
            raise self.err(fld, f"unknown pin {raw!r}: expected a BCM number, 'GPIOn' or 'BOARDn'")
        if v in RESERVED_BCM:
            raise self.err(fld, f"pin {raw!r} is GPIO{v}, reserved for {RESERVED_BCM[v]}")
        if v not in OUTPUT_BCM:
            raise self.err(fld, f"unknown pin {raw!r}: expected a BCM GPIO number 4..27")
        return v


# limits.*: (lo, hi).  A limit outside its range is a unit mistake or a disabled trip.
LIMIT_RANGES = {"rotor_temp_max_c": (20.0, 500.0), "overspeed_primary_rpm": (500.0, 20000.0),
                "overspeed_secondary_rpm": (500.0, 20000.0), "comms_timeout_s": (0.02, 5.0),
                "supervisor_timeout_s": (0.0, 65.0)}

_TOP_KEYS = {"schema", "protocol", "transport", "poll_hz", "derate", "debounce_primary_us",
             "debounce_secondary_us", "kill_relay", "pins", "i2c", "serial", "gear", "limits",
             "actuator", "throttle", "reset", "inertia", "control",
             "uncertainty", "driven", "torque_zero", "ambient", "input_torque", "driveline"}


def rig_from_dict(data: Mapping[str, Any], path: str | Path = "<rig>") -> RigConfig:
    """Validate a parsed rig description.

    Raises
    ------
    ConfigError
        naming the dotted field: unknown key or pin, duplicate pin, address out
        of 0x03..0x77, missing field, wrong type.
    """
    r = _Reader(str(path))
    r.no_extra(data, _TOP_KEYS, "")
    schema = r.string(data, "schema", "", required=False, default=SCHEMA)
    if schema != SCHEMA:
        raise r.err("schema", f"expected {SCHEMA!r}, got {schema!r}")

    # pins
    p = r.table(data, "pins")
    r.no_extra(p, set(PIN_NAMES) | set(OPTIONAL_INPUTS), "pins.")
    pins_by_name: dict[str, int] = {}
    for name in PIN_NAMES:
        bcm = r.pin(p, name)
        for other, other_bcm in pins_by_name.items():
            if other_bcm == bcm:
                raise r.err(f"pins.{name}", f"duplicate pin: GPIO{bcm} is already pins.{other}")
        pins_by_name[name] = bcm
    for name in ("brake_enable", "brake_direction"):
        # BCM 4..8 have pull-ups at power-on: the actuator would move while the
        # Pi boots, before dyno has claimed the pin.
        if pins_by_name[name] in BOOT_PULL_UP_BCM:
            raise r.err(f"pins.{name}", f"GPIO{pins_by_name[name]} is pulled up at boot (GPIO4..8); "
                        "use a pin pulled down at boot (GPIO9..27)")
    inputs: dict[str, int] = {}
    for name in OPTIONAL_INPUTS:
        if name in p:
            bcm = r.pin(p, name)
            for other, other_bcm in {**pins_by_name, **inputs}.items():
                if other_bcm == bcm:
                    raise r.err(f"pins.{name}", f"duplicate pin: GPIO{bcm} is already pins.{other}")
            inputs[name] = bcm
    pins = Pins(**pins_by_name, **inputs)

    # i2c
    t = r.table(data, "i2c")
    r.no_extra(t, {"bus", "firmware_address", "thermometer_address", "bus_speed_hz", "retries",
                   "retry_backoff_s", "reset_after_failures"}, "i2c.")
    a = dict(lo=I2C_ADDRESS_MIN, hi=I2C_ADDRESS_MAX, hexfmt=True)
    i2c = I2CConfig(
        bus=r.integer(t, "bus", "i2c.", lo=0, hi=255),
        firmware_address=r.integer(t, "firmware_address", "i2c.", **a),
        thermometer_address=r.integer(t, "thermometer_address", "i2c.", **a),
        # 10 kHz..400 kHz: below that the 150 Hz poll does not fit, above is fast-mode plus
        bus_speed_hz=r.integer(t, "bus_speed_hz", "i2c.", lo=10_000, hi=400_000),
        retries=r.integer(t, "retries", "i2c.", lo=0, hi=10, required=False, default=3),
        retry_backoff_s=r.number(t, "retry_backoff_s", "i2c.", lo=0.0, hi=1.0, required=False, default=0.002),
        reset_after_failures=r.integer(t, "reset_after_failures", "i2c.", lo=1, hi=10_000,
                                       required=False, default=20),
    )
    if i2c.firmware_address == i2c.thermometer_address:
        raise r.err("i2c.thermometer_address",
                    f"duplicate address 0x{i2c.thermometer_address:02X}: same as i2c.firmware_address")

    # serial
    t = r.table(data, "serial")
    r.no_extra(t, {"port", "baud", "timeout_s", "boot_timeout_s"}, "serial.")
    serial = SerialConfig(
        port=r.string(t, "port", "serial."),
        baud=r.integer(t, "baud", "serial.", lo=1200, hi=4_000_000),
        timeout_s=r.number(t, "timeout_s", "serial.", lo=0.001, hi=10.0, required=False, default=0.05),
        boot_timeout_s=r.number(t, "boot_timeout_s", "serial.", lo=0.5, hi=30.0, required=False, default=3.0),
    )

    # gear
    t = r.table(data, "gear")
    r.no_extra(t, {"secondary_sprocket_teeth", "brake_sprocket_teeth"}, "gear.")
    gear = Gear(
        secondary_sprocket_teeth=r.integer(t, "secondary_sprocket_teeth", "gear.", lo=1, hi=1000),
        brake_sprocket_teeth=r.integer(t, "brake_sprocket_teeth", "gear.", lo=1, hi=1000),
    )

    # limits
    t = r.table(data, "limits")
    lim_keys = ("rotor_temp_max_c", "overspeed_primary_rpm", "overspeed_secondary_rpm", "comms_timeout_s")
    r.no_extra(t, {*lim_keys, "supervisor_timeout_s"}, "limits.")
    limits = Limits(**{k: r.number(t, k, "limits.", lo=LIMIT_RANGES[k][0], hi=LIMIT_RANGES[k][1])
                       for k in lim_keys},
                    supervisor_timeout_s=r.number(t, "supervisor_timeout_s", "limits.", default=0.2, required=False,
                                                  lo=LIMIT_RANGES["supervisor_timeout_s"][0],
                                                  hi=LIMIT_RANGES["supervisor_timeout_s"][1]))

    # actuator
    t = r.table(data, "actuator")
    r.no_extra(t, {"step_s", "full_stroke_s", "relay_settle_s", "watchdog_s", "brake_hold_relay"}, "actuator.")
    actuator = ActuatorConfig(
        step_s=r.number(t, "step_s", "actuator.", lo=0.01, hi=10.0),
        full_stroke_s=r.number(t, "full_stroke_s", "actuator.", lo=0.5, hi=120.0),
        relay_settle_s=r.number(t, "relay_settle_s", "actuator.", lo=0.0, hi=1.0, required=False, default=0.03),
        watchdog_s=r.number(t, "watchdog_s", "actuator.", lo=0.05, hi=5.0, required=False, default=0.5),
        brake_hold_relay=r.boolean(t, "brake_hold_relay", "actuator.", False),
    )
    if actuator.step_s > actuator.full_stroke_s:
        raise r.err("actuator.step_s", f"expected <= actuator.full_stroke_s ({actuator.full_stroke_s})")

    # throttle: the servo accepts ~500..2500 us; anything else is a unit mistake (ms, duty %)
    t = r.table(data, "throttle")
    r.no_extra(t, {"idle_pulse_us", "full_pulse_us", "frame_us"}, "throttle.")
    throttle = ThrottleConfig(
        idle_pulse_us=r.number(t, "idle_pulse_us", "throttle.", lo=400, hi=2600),
        full_pulse_us=r.number(t, "full_pulse_us", "throttle.", lo=400, hi=2600),
        frame_us=r.number(t, "frame_us", "throttle.", lo=2500, hi=50000, required=False, default=20000.0),
    )
    for k in ("idle_pulse_us", "full_pulse_us"):
        if not 400 <= getattr(throttle, k) <= 2600:
            raise r.err(f"throttle.{k}", f"expected a servo pulse width 400..2600 us, got {getattr(throttle, k)}")
    if throttle.idle_pulse_us == throttle.full_pulse_us:
        raise r.err("throttle.full_pulse_us", "expected to differ from throttle.idle_pulse_us")
    if max(throttle.idle_pulse_us, throttle.full_pulse_us) >= throttle.frame_us:
        raise r.err("throttle.frame_us", "expected longer than both pulse widths")

    # reset (optional table)
    t = data.get("reset", {})
    if not isinstance(t, Mapping):
        raise r.err("reset", f"expected a table [reset], got {type(t).__name__}")
    r.no_extra(t, {"pulse_s", "boot_s", "active_high"}, "reset.")
    reset = ResetConfig(
        pulse_s=r.number(t, "pulse_s", "reset.", lo=0.001, hi=5.0, required=False, default=0.25),
        boot_s=r.number(t, "boot_s", "reset.", lo=0.0, hi=30.0, required=False, default=1.0),
        active_high=r.boolean(t, "active_high", "reset.", default=True),
    )
    t = data.get("driven", {})  # driven side and torque zero (optional tables)
    if not isinstance(t, Mapping):
        raise r.err("driven", f"expected a table [driven], got {type(t).__name__}")
    r.no_extra(t, {"loss_file", *DRIVEN_INERTIA_KEYS}, "driven.")
    driven = DrivenConfig(loss_file=r.string(t, "loss_file", "driven.", required=False, default=None))
    t = data.get("torque_zero", {})
    if not isinstance(t, Mapping):
        raise r.err("torque_zero", f"expected a table [torque_zero], got {type(t).__name__}")
    r.no_extra(t, {"read_s", "drift_max_nm", "correct", "tare"}, "torque_zero.")
    tz = TorqueZeroConfig()
    torque_zero = TorqueZeroConfig(
        read_s=r.number(t, "read_s", "torque_zero.", lo=0.2, hi=60.0, required=False, default=tz.read_s),
        drift_max_nm=r.number(t, "drift_max_nm", "torque_zero.", lo=0.0, hi=100.0, required=False,
                              default=tz.drift_max_nm),
        correct=r.boolean(t, "correct", "torque_zero.", default=tz.correct),
        tare=r.boolean(t, "tare", "torque_zero.", default=tz.tare),
    )

    # inertia, control (optional tables; defaults are the thesis rig's, as identified on the sim)
    inertia, deprecations = inertia_table(r, data)
    t = data.get("control", {})
    if not isinstance(t, Mapping):
        raise r.err("control", f"expected a table [control], got {type(t).__name__}")
    ranges = {"kp_speed": (0.01, 100.0), "lead_speed_s": (0.0, 5.0), "ff_speed_s": (0.0, 20.0),
              "kp_engine": (0.01, 100.0), "lead_engine_s": (0.0, 5.0),
              "kp_torque": (0.01, 100.0), "deadband_rel": (0.0, 0.2), "period_s": (0.005, 1.0),
              "min_pulse_s": (0.0, 1.0)}
    r.no_extra(t, set(ranges), "control.")
    control = ControlConfig(**{k: r.number(t, k, "control.", lo=lo, hi=hi, required=False,
                                           default=getattr(ControlConfig, k))
                               for k, (lo, hi) in ranges.items()})
    t = data.get("uncertainty", {})
    if not isinstance(t, Mapping):
        raise r.err("uncertainty", f"expected a table [uncertainty], got {type(t).__name__}")
    r.no_extra(t, {"engine_map_rel"}, "uncertainty.")
    uncertainty = UncertaintyConfig(engine_map_rel=r.number(t, "engine_map_rel", "uncertainty.", lo=0.0, hi=1.0,
                                                            required=False, default=UncertaintyConfig.engine_map_rel))
    if control.min_pulse_s > control.period_s:
        raise r.err("control.min_pulse_s", f"expected <= control.period_s ({control.period_s})")

    return RigConfig(
        path=str(path),
        protocol=r.string(data, "protocol", "", choices=("v2", "v1", "v0")),
        transport=r.string(data, "transport", "", choices=("i2c", "serial"), required=False, default="i2c"),
        poll_hz=r.number(data, "poll_hz", "", lo=1.0, hi=1000.0), derate=r.boolean(data, "derate", "", True),
        debounce_primary_us=r.integer(data, "debounce_primary_us", "", lo=0, hi=65535),
        debounce_secondary_us=r.integer(data, "debounce_secondary_us", "", lo=0, hi=65535),
        kill_relay=r.string(data, "kill_relay", "", choices=("energise_to_run", "energise_to_kill")),
        pins=pins, i2c=i2c, serial=serial, gear=gear, limits=limits,
        actuator=actuator, throttle=throttle, reset=reset, inertia=inertia, control=control,
        uncertainty=uncertainty, driven=driven, torque_zero=torque_zero, deprecations=deprecations,
        ambient=ambient_table(r, data), input_torque=input_torque_table(r, data), driveline=driveline_table(r, data),
    )


def resolve_rig_path(path: str | Path | None = None) -> Path:
    """The rig file a command reads (:func:`dyno.rig.locate.find_rig`)."""
    return find_rig(path).path


def load_rig(path: str | Path | None = None) -> RigConfig:
    """Read and validate a rig description (see :func:`resolve_rig_path`)."""
    p = resolve_rig_path(path)
    try:
        with open(p, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(p, "file", "not found") from None
    except OSError as exc:
        raise ConfigError(p, "file", f"unreadable ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(p, "toml", f"not valid TOML ({exc})") from None
    rig = rig_from_dict(data, p)
    for line in rig.deprecations:  # an old key that still loads: one line each, once per process
        if line not in _WARNED:
            _WARNED.add(line)
            print(f"dyno: warning: {line}", file=sys.stderr)
    return rig


_WARNED: set = set()


def load_rig_for(path: str | Path | None = None, *, sim: bool) -> RigConfig:
    """:func:`load_rig` of the found file; real hardware (``sim`` false) refuses the shipped one (dyno.rig.locate)."""
    found = find_rig(path)
    if not sim:
        require_own_rig(found)
    return load_rig(found.path)

