"""The link's time on the wire: what the busiest second costs at the rig file's clock, whether the poll rate
fits, and how busy the link really was.

**I²C.**  One combined transaction is, per message, a (repeated) START, the address byte and the data bytes —
9 SCL clocks each (8 bits and the ACK) — and one STOP at the end:

.. math::

    N_{SCL} = 1 + \\sum_{m} \\left(1 + 9\\,(1 + n_m)\\right)

A v2 poll (ACK_POLL, 6 bytes, then the fixed 32-byte read) is 363 clocks: 7.3 ms at 50 kHz, 3.6 ms at
100 kHz.  The rotor thermometer's read word (command, repeated start, 3 bytes) is 57 clocks, ten a second.

**USB serial** (8N1): 10 bits a byte; a poll is the COBS-framed request and the unpadded frame, each with one
more byte for COBS and one for the delimiter.

The planned share (:func:`planned_busy`) counts every transfer of the busiest second the rig file allows
(:mod:`dyno.transports.wire_load`): the polls, the MORE bursts the events at the over-speed limits force (both
converters on a rig with ``[input_torque]``), a poll's retries, the boot's commands and the supervisor's limits,
the thermometer's reads.  A rig whose planned share is above :data:`MAX_BUSY` of a second, or whose polls cannot
drain its events, is derated (``derate = true``, the default: the fastest poll rate that fits, said on stderr)
or refused (:func:`check_budget`).  :class:`LinkMeter` measures what a run really used, second by second: on the
simulator each transaction charged at the rig file's clock (:class:`MeteredBus`), on the rig each transfer
timed as it happens (:func:`metered_rig_link`).  A measured busiest second above :data:`MAX_BUSY` is a warning
of the run (``link.warnings``: ``"link_busy"``) and of ``dyno doctor``.

A bus clock above what a device on it is rated for is refused, naming the device (:data:`I2C_DEVICE_MAX_HZ`).
"""

from __future__ import annotations

from dyno.protocol.v2 import FRAME_MAX
from dyno.transports.wire_load import (busiest_second, busy_by_kind, i2c_clocks, poll_request_bytes, read_bytes,
                                       serial_bytes, transfer_s)

#: the share of any second a link may be planned busy, and above which a measured second is a warning
MAX_BUSY = 0.60
#: the fastest SCL each device on the rig's bus is rated for (datasheets): (rig.toml key, device, max Hz)
I2C_DEVICE_MAX_HZ = (("i2c.thermometer_address", "MLX90614 (its SMBus interface)", 100_000),
                     ("i2c.firmware_address", "ATmega328P TWI slave (the Nano)", 400_000))


def poll_s(rig) -> float:
    """One poll's time on the wire at the rig file's clock (on serial: with a full frame)."""
    return transfer_s(rig, poll_request_bytes(rig), read_bytes(rig))


def planned_busy(rig, poll_hz: float | None = None) -> float:
    """The share of the busiest second the link is busy at ``poll_hz`` (default: the rig file's): every
    transfer counted by :func:`dyno.transports.wire_load.busiest_second`, and the thermometer's reads."""
    return sum(busy_by_kind(rig, poll_hz).values())


def planned_by_kind(rig, poll_hz: float | None = None) -> dict:
    """:func:`planned_busy` by kind of transfer (poll, more, retry, boot, supervisor, thermometer), shares."""
    return {kind: round(busy, 4) for kind, busy in busy_by_kind(rig, poll_hz).items()}


def fits(rig, poll_hz: float | None = None) -> bool:
    """The polls at ``poll_hz`` (default: the rig file's) drain the busiest second's events and keep the link
    within :data:`MAX_BUSY`."""
    second = busiest_second(rig, poll_hz)
    return second.backlog == 0 and sum(busy_by_kind(rig, second=second).values()) <= MAX_BUSY


def clock_hz(rig) -> int:
    return rig.serial.baud if rig.transport == "serial" else rig.i2c.bus_speed_hz


def check_device_clocks(rig) -> None:
    """ConfigError naming ``i2c.bus_speed_hz`` and the device when the bus clock is above what it is rated for
    (the thermometer is on the Pi's bus on every rig; the Nano only where the firmware link is I²C)."""
    from dyno.errors import ConfigError

    for key, device, max_hz in I2C_DEVICE_MAX_HZ:
        if key == "i2c.firmware_address" and rig.transport != "i2c":
            continue
        if rig.i2c.bus_speed_hz > max_hz:
            address = getattr(rig.i2c, key.split(".", 1)[1])
            raise ConfigError(rig.path, "i2c.bus_speed_hz", f"at most {max_hz} Hz: the {device} at {key.split('.')[1]}"
                              f" = 0x{address:02X} is rated for {max_hz // 1000} kHz, not {rig.i2c.bus_speed_hz} Hz")


def min_poll_hz(rig) -> int:
    """The slowest poll rate a derate may choose: two polls a control decision (``control.period_s``: the
    load control then acts on data at most half a period old; slower, points go unsteady:
    docs/measurements/2026-12-05-link-budget.md), and two within the link's staleness
    limit (``limits.comms_timeout_s``) and the Nano's heartbeat timeout (``limits.supervisor_timeout_s``)."""
    import math

    periods = [rig.control.period_s, rig.limits.comms_timeout_s] + (
        [rig.limits.supervisor_timeout_s] if rig.limits.supervisor_timeout_s > 0 else [])
    return max(1, math.ceil(2.0 / min(periods) - 1e-9))


def max_poll_hz(rig) -> int:
    """The fastest whole poll rate, at most the rig file's, that :func:`fits`; 0: none from
    :func:`min_poll_hz` up."""
    for hz in range(int(rig.poll_hz), min_poll_hz(rig) - 1, -1):
        if fits(rig, hz):
            return hz
    return 0


def _why(rig, busy: float) -> str:
    clock = (f"{rig.serial.baud} Bd" if rig.transport == "serial" else f"{rig.i2c.bus_speed_hz} Hz SCL")
    by_kind = planned_by_kind(rig)
    events = by_kind.get("poll", 0.0) + by_kind.get("more", 0.0)
    thermometer = " and the thermometer" if "thermometer" in by_kind else ""
    return (f"on {rig.transport} at {clock} each poll is {poll_s(rig) * 1e3:.1f} ms on the wire; at the over-speed "
            f"limits {rig.poll_hz:g} Hz and its MORE bursts, retries, boot commands{thermometer} would keep the "
            f"link {100 * busy:.0f} % busy ({100 * events:.0f} % the polls), the limit is {100 * MAX_BUSY:.0f} %")


def check_budget(rig, say=None):
    """The rig as it will run: unchanged when its busiest second fits the link with the margin; else, with
    ``derate = true`` (the default), ``poll_hz`` lowered to :func:`max_poll_hz` and said on one stderr line;
    else a ConfigError naming ``poll_hz``.  A bus clock above a device's rating is a ConfigError naming
    ``i2c.bus_speed_hz``."""
    check_device_clocks(rig)
    if fits(rig, rig.poll_hz):
        return rig
    from dyno.errors import ConfigError

    busy = planned_busy(rig)
    why = _why(rig, busy)
    best = max_poll_hz(rig)
    if rig.derate and best >= 1:
        from dataclasses import replace

        line = f"{rig.path}: poll_hz: derated from {rig.poll_hz:g} Hz to {best} Hz ({why}; derate = true)"
        if line not in _SAID:
            _SAID.add(line)
            (say or _stderr)(line)
        return replace(rig, poll_hz=float(best), derated_from_hz=rig.poll_hz)
    if best >= 1:
        raise ConfigError(rig.path, "poll_hz", f"at most {best} Hz ({why}): lower poll_hz, set derate = true, or "
                          "a faster link (hardware/README.md, 'The Pi's I²C and clock stretching')")
    raise ConfigError(rig.path, "poll_hz", f"no poll rate from {min_poll_hz(rig)} Hz up fits ({why}): a faster "
                      "link (hardware/README.md, 'The Pi's I²C and clock stretching')")


_SAID: set = set()


def _stderr(line: str) -> None:
    import sys

    print(f"dyno: {line}", file=sys.stderr, flush=True)


class LinkMeter:
    """Seconds on the wire, bucketed by whole seconds of ``now_s``: the worst full second's busy share."""

    def __init__(self, now_s) -> None:
        self.now_s = now_s
        self._second: int | None = None
        self._busy_s = 0.0
        self.worst_busy = 0.0  # of the full seconds so far
        self.total_s = 0.0
        self.transactions = 0

    def add(self, busy_s: float) -> None:
        second = int(self.now_s())
        if second != self._second:
            if self._second is not None:
                self.worst_busy = max(self.worst_busy, self._busy_s)
            self._second, self._busy_s = second, 0.0
        self._busy_s += busy_s
        self.total_s += busy_s
        self.transactions += 1

    def worst_frac(self) -> float:
        """The worst full second's share (the second under way counts once it is one: no partial inflation)."""
        return self.worst_busy


class MeteredBus:
    """An SMBus-like bus whose every ``i2c_rdwr`` is charged to a :class:`LinkMeter`: at ``rig``'s I²C clock,
    or — a simulated rig whose firmware is on USB serial — at its baud rate, as the serial exchange of the same
    request and frame would take (:func:`serial_bytes`; the frame unpadded)."""

    def __init__(self, bus, meter: LinkMeter, rig) -> None:
        self.bus = bus
        self.meter = meter
        self.serial_baud = float(rig.serial.baud) if rig.transport == "serial" else None
        self.clock_hz = float(rig.i2c.bus_speed_hz)

    def i2c_rdwr(self, *msgs):
        if self.serial_baud is None:
            self.meter.add(i2c_clocks([(m.flags & 1, m.len) for m in msgs]) / self.clock_hz)
            return self.bus.i2c_rdwr(*msgs)
        result = self.bus.i2c_rdwr(*msgs)
        written = sum(m.len for m in msgs if not m.flags & 1)
        read = [bytes(m) for m in msgs if m.flags & 1]
        frame = read[0][1] if read and len(read[0]) > 1 and 0 < read[0][1] <= FRAME_MAX else 0
        self.meter.add(10 * serial_bytes(written, frame) / self.serial_baud)
        return result

    def __getattr__(self, name):  # close(), the simulated bus's knobs: the bus's own
        return getattr(self.bus, name)


class ChargedTransport:
    """A transport whose every transfer is charged to a :class:`LinkMeter` at ``rig``'s clock from the bytes it
    moved (a simulated link, whose transfers take no time of the clock: ``dyno doctor --sim``); on serial the
    answer's own length (byte 1 of a frame), on I²C the fixed read."""

    def __init__(self, transport, meter: LinkMeter, rig) -> None:
        self.transport = transport
        self.meter = meter
        self.rig = rig

    def transfer(self, request: bytes, read_len: int) -> bytes:
        answer = 0
        try:
            data = self.transport.transfer(request, read_len)
            answer = (data[1] if len(data) > 1 and 0 < data[1] <= read_len else 0) if self.rig.transport == "serial" \
                else read_len
            return data
        finally:
            self.meter.add(transfer_s(self.rig, len(request), answer if self.rig.transport == "serial" else read_len))

    def write(self, request: bytes) -> None:
        try:
            self.transport.write(request)
        finally:
            self.meter.add(transfer_s(self.rig, len(request), 0))

    def __getattr__(self, name):
        return getattr(self.transport, name)


def metered_rig_link(hw, rig, clock=None):
    """(transport, thermometer read, meter) of a real rig: each attempt of the firmware transport timed as it
    happens (:meth:`dyno.transports.base.Transport.meter_with`); the thermometer's reads are charged too where
    they share the firmware's I²C bus."""
    import time

    clock = clock or time.monotonic
    meter = LinkMeter(clock)
    hw.transport.meter_with(meter, clock)
    read_c = hw.thermometer.object_c
    if rig.transport == "i2c":
        def read_c(_read=hw.thermometer.object_c):
            t0 = clock()
            try:
                return _read()
            finally:
                meter.add(clock() - t0)
    return hw.transport, read_c, meter
