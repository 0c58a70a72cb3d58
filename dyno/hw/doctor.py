"""The rig's diagnosis (``dyno doctor``, :mod:`dyno.cli.doctor_cmd` its command line): check the hardware and
report what works.  Library code: :func:`diagnose` takes its parts as typed arguments (a :class:`DoctorSpec`,
built by :func:`doctor_spec` from the rig file and what to do) and returns a :class:`Report`.

Read-only unless ``--toggle``: without it no GPIO pin is claimed (claiming a
pin drives it), so doctor is safe to run with the engine running.  With
``--toggle`` it pulses the Arduino reset (and checks the boot counter moved),
steps the brake actuator out and back by one ``actuator.step_s``, and leaves
everything in the safe state.

The command's exit status: 0 all essential checks pass, 1 an essential check failed, 2 the
rig description is invalid (from the CLI's ConfigError handling).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path


from dyno.hw.doctor_report import FAIL, OK, SKIP, WARN, Report
from dyno.hw.doctor_switch import switch_sample, check_end_switch, check_end_switch_k3, check_safety_inputs


def _i2c_clock_hz(bus_number: int) -> int | None:
    """The kernel's actual I2C clock, from the device tree (None if unknown)."""
    p = Path(f"/sys/class/i2c-adapter/i2c-{bus_number}/of_node/clock-frequency")
    try:
        raw = p.read_bytes()
    except OSError:
        return None
    return int.from_bytes(raw[:4], "big") if len(raw) >= 4 else None


def check_firmware(report: Report, cfg, transport) -> object | None:
    """INFO (v1) or one plain read (v0); returns the info frame if any."""
    from dyno.acquisition.reader import make_reader
    from dyno.errors import FrameError
    from dyno.protocol import v0

    if cfg.protocol == "v0":
        try:
            buf = transport.transfer(b"", v0.FRAME_LEN)
            f = v0.decode_legacy_frame(buf)
        except (OSError, FrameError) as exc:
            report.add("firmware", FAIL, f"v0 read failed: {exc}")
            return None
        report.add("firmware", OK, f"v0 sketch answers (primary {f.rpm_primary} rpm, ADC code {f.adc_code})")
        return f
    reader = make_reader(cfg.protocol, transport)
    info = None
    for _ in range(3):  # the first read after a host restart may still be a data frame in flight
        info = reader.read_info()
        if info is not None:
            break
    if info is None:
        report.add("firmware", FAIL, _no_info_hint(cfg, dict(transport.failures), reader))
        return None
    major, minor, patch = info.fw_version
    if cfg.protocol == "v2":
        from dyno.protocol.v2 import cause_name

        boot = f"boot id 0x{info.boot_id:04x} (reset cause: {cause_name(info.reset_cause)})"
    else:
        boot = f"boot #{info.boot_count}"
    report.add("firmware", OK, f"v{major}.{minor}.{patch}, {boot}, up {info.uptime_ms / 1000:.1f} s")
    want = (cfg.debounce_primary_us, cfg.debounce_secondary_us)
    have = (info.debounce_primary_us, info.debounce_secondary_us)
    report.add("debounce", OK if have == want else WARN,
               f"device {have[0]}/{have[1]} us, rig file {want[0]}/{want[1]} us"
               + ("" if have == want else " (dyno sends SET_DEBOUNCE at start)"), essential=False)
    if cfg.protocol == "v2":
        from dyno.hw.doctor_nano import check_run_enable

        check_run_enable(report, OK, WARN, SKIP, cfg, transport)
    return info


def _no_info_hint(cfg, fails: dict, reader) -> str:
    """Why no INFO frame came, told by how the transfers failed (a NACK is not a CRC failure)."""
    where = cfg.serial.port if cfg.transport == "serial" else f"0x{cfg.i2c.firmware_address:02X} on /dev/i2c-{cfg.i2c.bus}"
    rejected = dict(getattr(reader.stats, "rejected", {}) or {})
    if fails.get("nack"):
        return (f"no answer at {where} ({fails}): the Nano not powered or not flashed, SDA/SCL swapped or loose, "
                "the level shifter, or [i2c] firmware_address wrong (i2cdetect -a -y BUS lists it)")
    if fails.get("stretch_timeout"):
        return (f"clock-stretch timeouts at {where} ({fails}): the Pi's Broadcom controller and the Nano's stretching "
                "(hardware/README.md: i2c-gpio or USB serial)")
    if fails.get("timeout"):
        return f"bus timeouts at {where} ({fails}): a bus held low (reset the Nano), or the USB cable"
    if rejected:
        return (f"answers at {where}, but every frame was rejected ({rejected}): CRC failures are noise or a sketch "
                f"of another protocol (rig.toml protocol = \"{cfg.protocol}\"; a v0 thesis sketch: protocol = \"v0\")")
    return f"answers at {where}, but no {cfg.protocol} info frame ({fails or 'no failure counted'}): another sketch?"


def check_estop_input(report: Report, cfg, pin_factory=None) -> None:
    """Read-only: the E-stop chain's monitor input (an input claimed, nothing driven)."""
    from gpiozero import Button

    bcm = cfg.pins.estop_input
    try:
        button = Button(bcm, pull_up=True, pin_factory=pin_factory)
    except Exception as exc:  # noqa: BLE001 - gpiozero's pin errors: in use (the service runs?), no GPIO here
        report.add("e-stop input", FAIL, f"GPIO{bcm} (pins.estop_input) cannot be read: {exc} (is dyno running?)")
        return
    try:
        closed = button.is_pressed
    finally:
        button.close()
    report.add("e-stop input", OK if closed else FAIL,
               f"GPIO{bcm}: chain closed" if closed else
               f"GPIO{bcm}: chain OPEN (a button pressed, or the chain's wire or connector: check the E-stop chain)")


def check_thermometer(report: Report, cfg, bus) -> None:
    from dyno.errors import TransportError
    from dyno.hw.thermometer import MLX90614

    t = MLX90614(bus, cfg.i2c.thermometer_address)
    try:
        obj, amb = t.object_c(), t.ambient_c()
    except TransportError as exc:
        report.add("thermometer", FAIL, f"0x{cfg.i2c.thermometer_address:02X}: {exc}")
        return
    limit = cfg.limits.rotor_temp_max_c
    status = OK if obj < limit else FAIL
    report.add("thermometer", status, f"rotor {obj:.1f} C (limit {limit:.0f} C), sensor {amb:.1f} C")


def check_ambient(report: Report, cfg, bus) -> None:
    """The BME280 when rig.toml fits one: it answers, and with a day a dyno can run on (and its J1349 factor)."""
    amb = cfg.ambient
    if amb.sensor != "bme280":
        given = amb.given()
        report.add("ambient", OK if given else WARN,
                   f"no sensor; rig.toml gives {given.temp_c:g} C, {given.pressure_kpa:g} kPa" if given else
                   "no sensor and no day in rig.toml [ambient]: runs are uncorrected unless given --ambient "
                   "(docs/analysis.md)", essential=False)
        return
    if bus is None:
        report.add("ambient", FAIL, "BME280: no I2C bus")
        return
    from dyno.errors import ConfigError
    from dyno.hw.bme280 import BME280, read_sensor

    try:
        a = read_sensor(BME280(bus, amb.address), "BME280")
    except ConfigError as exc:
        report.add("ambient", FAIL, f"0x{amb.address:02X}: {exc.expected}")
        return
    report.add("ambient", OK, f"BME280 0x{amb.address:02X}: {a.temp_c:.1f} C, {a.pressure_kpa:.2f} kPa, "
               f"{a.rh_pct:.0f} %RH: SAE J1349 factor {a.j1349_factor:.4f}")


def check_outputs(report: Report, cfg, transport, clock=None, pin_factory=None, bus=None, serial_port=None) -> None:
    """--toggle: claims the pins (driving them safe), pulses reset, steps the brake.

    The rig comes from the one composition root every entry point uses
    (:class:`dyno.hw.rig.HardwareRig`): signal handlers that reach the safe state
    first, the E-stop input if wired, and the watchdog on its own thread, so a hang
    in a bus transfer while the brake moves still ends in the safe state.
    """
    from dyno.control.outputs import APPLY, RELEASE
    from dyno.hw.rig import HardwareRig

    # the firmware link diagnose() opened is handed over: a second open of a serial port resets the Nano again
    hw = HardwareRig(cfg, pin_factory=pin_factory, clock=clock, bus=bus, serial_port=serial_port,
                     firmware_transport=transport if cfg.transport == "serial" or serial_port is not None else None)
    try:
        hw.__enter__()
    except Exception as exc:  # gpiozero raises a family of pin errors; report, don't crash
        report.add("gpio", FAIL, f"cannot claim pins {cfg.pins.as_dict()}: {exc}")
        return
    try:
        hw.watchdog.start_thread()
        act = hw.actuators
        report.add("gpio", OK, "pins claimed; throttle idle, engine killed, brake releasing; watchdog running")
        if hw.estop is not None:
            report.add("e-stop input", FAIL if hw.estop.is_open else OK,
                       f"GPIO{hw.estop.bcm}: chain {'OPEN (stop)' if hw.estop.is_open else 'closed'}")
            if hw.estop.is_open:
                return
        if not act.finish_release():
            report.add("brake release", FAIL, "release stroke did not complete")
            return
        report.add("brake release", OK, f"released ({cfg.actuator.full_stroke_s:.1f} s stroke)", essential=False)
        before = boot_identity(cfg, transport)
        act.reset_arduino()
        after = boot_identity_after_reset(cfg, transport, before, act.clock, act)
        if cfg.protocol in ("v1", "v2") and before is not None:
            moved = after is not None and after != before
            what = "boot id" if cfg.protocol == "v2" else "boot count"
            report.add("arduino reset", OK if moved else FAIL,
                       f"{what} {before} -> {after}" + ("" if moved else ": reset line not wired?"))
        else:
            report.add("arduino reset", WARN, "pulsed; cannot confirm without an INFO frame", essential=False)
        if cfg.actuator.brake_hold_relay:
            # K3's NO contacts carry the driver's path: the step needs the kill chain closed (dyno.hw.doctor_switch)
            check_end_switch_k3(report, cfg, hw, transport, act.clock)
            return
        at_stop = switch_sample(act)
        act.step(APPLY, cfg.actuator.step_s)
        out = switch_sample(act)
        act.step(RELEASE, cfg.actuator.step_s)
        if hw.watchdog.tripped:
            report.add("brake step", FAIL, "the watchdog tripped during the step")
            return
        report.add("brake step", OK, f"{cfg.actuator.step_s:.2f} s out and back (watch the actuator move)",
                   essential=False)
        if at_stop is not None:
            act.safe_state()  # back to the retracted stop, the switch confirming (or the full stroke)
            act.finish_release()
            check_end_switch(report, cfg, act, at_stop, out, switch_sample(act), hw.persist_faults)
    finally:
        hw.__exit__(None, None, None)  # release stroke finished, outputs de-energised, pins released


#: after a reset, how long the new boot may take to answer (Optiboot ~1 s after an external reset + start-up)
BOOT_DEADLINE_S = 3.0


def boot_identity_after_reset(cfg, transport, before, clock, act=None):
    """The boot identity after a reset: asked until it differs from ``before`` or :data:`BOOT_DEADLINE_S` has
    passed (a fixed wait shorter than the bootloader read the old boot, or none: "reset line not wired?")."""
    end = clock.now() + BOOT_DEADLINE_S
    while True:
        now_boot = boot_identity(cfg, transport)
        if (now_boot is not None and now_boot != before) or clock.now() >= end:
            return now_boot
        clock.sleep(0.1)
        if act is not None:
            act.tick(clock.now())  # (doctor is the loop here: its tick is the watchdog's sign of life)


def boot_identity(cfg, transport):
    """The device's boot identity: v2 boot id (new on every boot), v1 EEPROM boot count."""
    if cfg.protocol not in ("v1", "v2"):
        return None
    from dyno.acquisition.reader import make_reader

    info = make_reader(cfg.protocol, transport).read_info()
    if info is None:
        return None
    return info.boot_id if cfg.protocol == "v2" else info.boot_count


def diagnose(cfg, *, bus=None, serial_port=None, transport_kind=None, toggle=False,
             clock=None, pin_factory=None, operator=None) -> Report:
    """All checks; ``bus``/``serial_port`` inject fakes or the simulated bus."""
    from dyno.hw.doctor_link import check_data, check_link_budget
    from dyno.transports.i2c import open_i2c, smbus_factory
    from dyno.transports.serial import open_serial

    report = Report()
    injected = bus is not None  # a simulated or fake bus: no real pins behind this doctor
    report.add("rig file", OK, f"{cfg.path} (protocol {cfg.protocol}, poll {cfg.poll_hz:g} Hz)", essential=False)
    check_safety_inputs(report, cfg)
    kind = transport_kind or cfg.transport
    run_cfg = check_link_budget(report, cfg if kind == cfg.transport else replace(cfg, transport=kind))

    # I2C bus: needed for the thermometer even when the firmware is on USB serial.
    if bus is None:
        try:
            bus = smbus_factory(cfg.i2c.bus)()
        except PermissionError as exc:
            report.add("i2c bus", FAIL, f"{exc}: add the user to the i2c group (sudo usermod -aG i2c $USER, "
                       "then log in again)")
            bus = None
        except OSError as exc:
            report.add("i2c bus", FAIL, str(exc))
            bus = None
        else:
            actual = _i2c_clock_hz(cfg.i2c.bus)
            if actual is None:
                report.add("i2c bus", OK, f"/dev/i2c-{cfg.i2c.bus} open (clock unknown)")
            elif actual > cfg.i2c.bus_speed_hz:
                report.add("i2c bus", WARN, f"/dev/i2c-{cfg.i2c.bus} runs at {actual} Hz, rig file says "
                           f"{cfg.i2c.bus_speed_hz} Hz: set dtparam=i2c_arm_baudrate (hardware/README.md)",
                           essential=False)
            else:
                report.add("i2c bus", OK, f"/dev/i2c-{cfg.i2c.bus} open at {actual} Hz")
    else:
        report.add("i2c bus", OK, f"{type(bus).__name__} (injected)", essential=False)

    transport = None
    if kind == "serial":
        try:
            transport = open_serial(cfg, port=serial_port, clock=clock)
            report.add("serial", OK, f"{cfg.serial.port} at {cfg.serial.baud} Bd"
                       + (f" ({type(serial_port).__name__}: injected)" if serial_port is not None else ""))
        except OSError as exc:
            report.add("serial", FAIL, str(exc))
    elif bus is not None:
        transport = open_i2c(cfg, bus=bus, clock=clock)
    info = None
    if transport is not None:
        info = check_firmware(report, cfg, transport)
    else:
        report.add("firmware", FAIL, "no link to the firmware")
    if info is not None and cfg.protocol in ("v1", "v2"):
        check_data(report, run_cfg, transport, clock, operator, simulated=injected or serial_port is not None)

    if bus is not None:
        check_thermometer(report, cfg, bus)
    else:
        report.add("thermometer", FAIL, "no I2C bus")
    check_ambient(report, cfg, bus)

    if not toggle and cfg.pins.estop_input is not None and (pin_factory is not None or not injected):
        check_estop_input(report, cfg, pin_factory)
    if toggle:
        if transport is None:
            report.add("gpio", FAIL, "not toggled: no firmware link to confirm the reset")
        else:
            check_outputs(report, cfg, transport, clock=clock, pin_factory=pin_factory, bus=bus,
                          serial_port=serial_port)
    else:
        report.add("gpio", SKIP, "outputs not touched (use --toggle)", essential=False)
    return report


@dataclass(frozen=True)
class DoctorSpec:
    """What :func:`diagnose` examines and how: the rig file's description and the parts to use (None: the
    real ones, opened by the diagnosis; the simulated rig's by :func:`dyno.session.doctor_rig.doctor_spec`)."""

    cfg: object  # dyno.rig.config.RigConfig
    toggle: bool = False  # exercise the outputs (reset pulse, a brake step out and back)
    transport_kind: str | None = None  # "i2c" | "serial" (None: the rig file's)
    bus: object = None
    serial_port: object = None
    clock: object = None
    pin_factory: object = None
    operator: object = None  # who turns the rig by hand for the data check (a terminal, the simulated one)


def run_diagnosis(spec: DoctorSpec) -> Report:
    """:func:`diagnose` with the spec's parts (the driver's own log findings are the report's lines)."""
    import logging

    logging.getLogger("dyno.outputs").setLevel(logging.CRITICAL)
    return diagnose(spec.cfg, bus=spec.bus, transport_kind=spec.transport_kind, toggle=spec.toggle,
                    serial_port=spec.serial_port, clock=spec.clock, pin_factory=spec.pin_factory,
                    operator=spec.operator)
