"""The firmware over the Pi's I²C bus (smbus2), with retry, bus recovery and reset.

:class:`RecoveringI2CTransport` keeps the base class's one combined
``i2c_rdwr`` per poll and adds, below the protocol:

* retry with exponential back-off inside one ``transfer``.  Re-sending the
  same request is safe in v1: ``ACK_POLL(seq)`` for a frame the device
  already retired just serves the current frame again (docs/protocol.md);
* bus recovery after a stuck transfer (ETIMEDOUT): close and reopen
  ``/dev/i2c-N``.  That only renews the open file: it does not reset the
  controller (the Broadcom driver resets its FIFO and state at every
  transfer anyway).  A bus held low by the slave needs the classic 9-clock
  SDA release, which needs the pins as GPIO: with the ``i2c-gpio`` overlay
  (the shipped rig's bus) the kernel does it itself, on the Broadcom
  controller only the Nano's reset below frees it (hardware/README.md);
* on the Broadcom controller (buses 0/1 of a Pi up to the 4) an EIO is its
  clock-stretch timeout, counted as ``stretch_timeout`` (hardware/README.md:
  the Nano stretches SCL), not as a NACK;
* an Arduino reset (via the reset pin) after N consecutive failed transfers,
  because a Nano whose TWI state machine has wedged holding SDA low never
  recovers on its own.  Its RESET flag then starts a new time epoch.

Failures still reach the caller as ``TransportFault`` so the reader counts them.
"""

from __future__ import annotations

import errno
from collections import Counter

from dyno.clock import MonotonicClock
from dyno.transports.base import STRETCH_CAUSES, I2CTransport, TransportFault


#: after pulsing RESET, no other reset for this long: the new boot answers within it (Optiboot ~1 s + setup)
RESET_GRACE_S = 3.0


class RecoveringI2CTransport(I2CTransport):
    name = "i2c"

    def __init__(self, bus, address: int, *, retries: int = 3, retry_backoff_s: float = 0.002,
                 reset_after_failures: int = 20, reopen=None, reset=None, clock=None) -> None:
        super().__init__(bus, address)
        self.retries = int(retries)
        self.retry_backoff_s = float(retry_backoff_s)
        self.reset_after_failures = int(reset_after_failures)
        self._reopen = reopen  # () -> new bus; None: recovery not possible (e.g. simulated bus)
        self._reset = reset  # () -> None, pulses the Arduino's RESET
        self.clock = clock or MonotonicClock()
        self.consecutive_failures = 0
        self.retried: Counter = Counter()  # attempts that failed but were retried, by cause
        self.recoveries = 0
        self.resets = 0
        self._next_reset_s = float("-inf")

    def _transfer(self, request: bytes, read_len: int) -> bytes:
        delay = self.retry_backoff_s
        last: BaseException | None = None
        for attempt in range(self.retries + 1):
            try:
                data = super()._transfer(request, read_len)
            except (OSError, TransportFault) as exc:
                last = exc
                cause = exc.cause if isinstance(exc, TransportFault) else self.errno_cause.get(exc.errno, "io")
                if cause == "timeout":
                    self._recover_bus()
                if attempt < self.retries:
                    self.retried[cause] += 1
                    self.clock.sleep(delay)
                    delay *= 2
                continue
            self.consecutive_failures = 0
            return data
        self.consecutive_failures += 1
        if (self._reset is not None and self.consecutive_failures >= self.reset_after_failures
                and self.clock.now() >= self._next_reset_s):
            self.consecutive_failures = 0
            self.resets += 1
            self._reset()
            # the Nano's bootloader listens ~1 s after an external reset before the sketch (and its I2C slave)
            # starts: the NACKs until then are the reset's, not a reason for another one
            self._next_reset_s = self.clock.now() + RESET_GRACE_S
        assert last is not None
        raise last

    def _recover_bus(self) -> None:
        if self._reopen is None:
            return
        try:
            close = getattr(self.bus, "close", None)
            if close:
                close()
        except OSError:
            pass
        try:
            self.bus = self._reopen()
            self.recoveries += 1
        except OSError as exc:  # adapter gone: the retry will fail and be counted
            raise TransportFault("io", f"bus reopen failed: {exc}") from exc


def missing_bus_hint(bus_number: int) -> str:
    """How a missing ``/dev/i2c-<n>`` is made on a Pi: bus 1 is the hardware controller (raspi-config); any
    other number is a software bus from the ``i2c-gpio`` overlay (the shipped rig's bus 3, docs/install-pi.md)."""
    if bus_number == 1:
        return "enable I2C: sudo raspi-config nonint do_i2c 0, then reboot"
    return (f"bus {bus_number} is i2c-gpio's: dtoverlay=i2c-gpio,bus={bus_number},i2c_gpio_sda=5,i2c_gpio_scl=6 "
            "in /boot/firmware/config.txt (the pins your wiring uses), then reboot; docs/install-pi.md")


def smbus_factory(bus_number: int):
    """A callable opening ``/dev/i2c-<n>`` (imported lazily: laptops have no smbus2 device)."""

    def open_bus():
        from smbus2 import SMBus

        try:
            return SMBus(bus_number)
        except FileNotFoundError as exc:
            raise OSError(errno.ENODEV, f"/dev/i2c-{bus_number} not found ({missing_bus_hint(bus_number)})") from exc

    return open_bus


def open_i2c(config, *, bus=None, reset=None, clock=None, address=None) -> RecoveringI2CTransport:
    """The firmware transport for a :class:`dyno.rig.config.RigConfig`.

    ``bus`` defaults to ``smbus2.SMBus(config.i2c.bus)`` (reopened on recovery);
    pass the simulated bus to run the same code off the rig.  ``reset`` is
    usually ``GpioActuators.reset_arduino``.
    """
    c = config.i2c
    reopen = None
    if bus is None:
        reopen = smbus_factory(c.bus)
        bus = reopen()
    transport = RecoveringI2CTransport(
        bus, c.firmware_address if address is None else address,
        retries=c.retries, retry_backoff_s=c.retry_backoff_s,
        reset_after_failures=c.reset_after_failures, reopen=reopen, reset=reset, clock=clock)
    if hardware_controller(c.bus):
        transport.errno_cause = STRETCH_CAUSES
    return transport


def hardware_controller(bus_number: int) -> bool:
    """Buses 0 and 1 are the SoC's I2C controller (Broadcom on a Pi up to the 4: the clock-stretching bug);
    i2c-gpio overlays take the next numbers (the shipped rig: bus 3)."""
    return bus_number in (0, 1)
