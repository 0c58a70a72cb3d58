"""Bring-up (issue 40): the serial port's auto-reset and a doctor that finds wiring faults.

The simulated Nano on USB serial resets when its port opens and answers nothing while its bootloader listens
(dyno/sim/serial_port.py); the doctor reads data frames channel by channel (dyno/hw/doctor_data.py).
"""

from __future__ import annotations

import pytest

from dyno.acquisition.reader import make_reader
from dyno.clock import FakeClock
from dyno.rig.config import load_rig
from dyno.sim.device import BOOTLOADER_S
from dyno.sim.rig import SimRig
from dyno.sim.serial_port import SimSerialPort
from dyno.transports.base import TransportFault
from dyno.transports.serial import open_serial

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def _sim():
    clock = FakeClock(start_s=0.0)
    sim = SimRig(clock.now)
    clock.advance(2.0)  # the rig has been on a while: the port is opened on a running Nano
    return sim, clock


def test_opening_the_port_resets_the_nano_and_the_host_waits_for_its_new_boot():
    sim, clock = _sim()
    cfg = load_rig()
    boot_before = sim.firmware.boot_id
    t_open = clock.now()
    transport = open_serial(cfg, port=SimSerialPort(sim, clock), clock=clock)
    assert sim.firmware.boot_id != boot_before  # DTR reset it
    assert clock.now() - t_open >= BOOTLOADER_S  # ... and the open waited the bootloader out
    info = make_reader("v2", transport).read_info()
    assert info is not None and info.boot_id == sim.firmware.boot_id


def test_the_old_open_asked_at_once_and_met_the_bootloader():
    """What dyno did before: no wait after the open; `dyno doctor`'s three 50 ms INFO tries all landed in
    Optiboot and it said the firmware was not there."""
    sim, clock = _sim()
    port = SimSerialPort(sim, clock)
    transport = open_serial(load_rig(), port=port, clock=clock, wait_boot=False)
    reader = make_reader("v2", transport)
    assert all(reader.read_info() is None for _ in range(3))
    assert port.ignored_in_bootloader >= 3


def test_a_port_that_never_answers_is_one_line_naming_it():
    sim, clock = _sim()
    sim.firmware.boot_time_s = float("inf")  # a Nano that never starts its sketch (not flashed)
    with pytest.raises(TransportFault, match="ttyUSB0: no frame within 3 s"):
        open_serial(load_rig(), port=SimSerialPort(sim, clock, reset_on_open=False), clock=clock)


def test_after_a_reset_the_doctor_waits_for_the_new_boot_not_a_fixed_time():
    from dyno.hw.doctor import boot_identity, boot_identity_after_reset

    sim, clock = _sim()
    cfg = load_rig()
    transport = open_serial(cfg, port=SimSerialPort(sim, clock), clock=clock)
    before = boot_identity(cfg, transport)
    sim.bus.sync()
    sim.firmware.reset(clock.now(), cause=0x2)  # the RESET line: the bootloader listens ~1 s again
    clock.advance(1.0)  # [reset] boot_s: the old fixed wait, shorter than the bootloader's
    assert boot_identity(cfg, transport) is None  # what the old check read: "reset line not wired?"
    assert boot_identity_after_reset(cfg, transport, before, clock) == before + 1


def test_the_open_sends_nothing_into_a_talking_bootloader_and_drops_what_it_said():
    """Optiboot is not silent (its LED, a clone's banner): the open waits out its window and its chatter, and
    the first frame read is the new sketch's."""
    sim, clock = _sim()
    port = SimSerialPort(sim, clock)
    t_open = clock.now()
    transport = open_serial(load_rig(), port=port, clock=clock)
    assert port.noise_bytes > 20  # the bootloader talked ...
    assert port.taken_by_bootloader == 0  # ... and not one host byte reached it
    assert clock.now() - t_open >= BOOTLOADER_S
    info = make_reader("v2", transport).read_info()
    assert info is not None and info.boot_id == sim.firmware.boot_id


def test_the_old_half_second_wait_sent_into_the_bootloaders_window(monkeypatch):
    import dyno.transports.serial as serial_mod

    monkeypatch.setattr(serial_mod, "BOOT_WINDOW_S", 0.5)  # what dyno did before: 0.5 s, then ask
    monkeypatch.setattr(serial_mod, "BOOT_QUIET_GAP_S", 0.0)
    sim, clock = _sim()
    port = SimSerialPort(sim, clock)
    open_serial(load_rig(), port=port, clock=clock)
    assert port.taken_by_bootloader > 0


def test_a_bootloader_that_talks_past_the_usual_window_is_let_finish(monkeypatch):
    import dyno.sim.device as device

    monkeypatch.setattr(device, "BOOTLOADER_S", 1.8)  # an old or slow bootloader: ~1.8 s before the sketch
    sim, clock = _sim()
    port = SimSerialPort(sim, clock, bootloader_talks_s=1.7)
    t_open = clock.now()
    transport = open_serial(load_rig(), port=port, clock=clock)
    assert port.taken_by_bootloader == 0 and clock.now() - t_open >= 1.8
    assert make_reader("v2", transport).read_info().boot_id == sim.firmware.boot_id


def test_a_missing_software_bus_names_the_i2c_gpio_overlay_not_raspi_config():
    from dyno.transports.i2c import smbus_factory

    with pytest.raises(OSError) as bus3:
        smbus_factory(97)()  # (no /dev/i2c-97 anywhere): the shipped rig's bus 3 is made the same way
    assert "dtoverlay=i2c-gpio,bus=97" in str(bus3.value) and "raspi-config" not in str(bus3.value)
    from dyno.transports.i2c import missing_bus_hint

    assert "raspi-config" in missing_bus_hint(1)  # the hardware controller's bus is the one raspi-config enables
