"""The link's time on the wire: what a poll costs at the rig file's clock, whether the poll rate fits, and
how busy the link really was.

**I²C.**  One combined transaction is, per message, a (repeated) START, the address byte and the data bytes —
9 SCL clocks each (8 bits and the ACK) — and one STOP at the end:

.. math::

    N_{SCL} = 1 + \\sum_{m} \\left(1 + 9\\,(1 + n_m)\\right)

A v2 poll (ACK_POLL, 6 bytes, then the fixed 32-byte read) is 363 clocks: 7.3 ms at 50 kHz, 3.6 ms at
100 kHz.  The rotor thermometer's read word (command, repeated start, 3 bytes) is 57 clocks, ten a second.

**USB serial** (8N1): 10 bits a byte; a poll is the COBS-framed request and the unpadded frame, each with one
more byte for COBS and one for the delimiter.

A rig whose planned polls (:func:`planned_busy`) would keep its link busier than :data:`MAX_BUSY` of a second
is refused (:func:`check_budget`): the margin is for the bursts when the device says MORE, the re-polls after
a rejected frame, the retries.  :class:`LinkMeter` measures what a run really used, second by second: on the
simulator each transaction charged at the rig file's clock (:class:`MeteredBus`), on the rig each transfer
timed as it happens (:func:`metered_rig_link`).  A measured busiest second above :data:`MAX_BUSY` is a warning
of the run (``link.warnings``: ``"link_busy"``).

A bus clock above what a device on it is rated for is refused, naming the device (:data:`I2C_DEVICE_MAX_HZ`).
"""

from __future__ import annotations

#: the share of any second a link may be planned busy
MAX_BUSY = 0.60
#: one v2 poll's request (ACK_POLL: op, boot id, seq, CRC-16) and the fixed read (docs/protocol.md)
POLL_REQUEST_BYTES = 6
FRAME_BYTES = 32
#: the MLX90614's read word: command byte written, 3 bytes read (2 data + PEC); the poller's rate of it
THERMOMETER_MSGS = ((False, 1), (True, 3))
THERMOMETER_HZ = 10.0
#: the fastest SCL each device on the rig's bus is rated for (datasheets): (rig.toml key, device, max Hz)
I2C_DEVICE_MAX_HZ = (("i2c.thermometer_address", "MLX90614 (its SMBus interface)", 100_000),
                     ("i2c.firmware_address", "ATmega328P TWI slave (the Nano)", 400_000))


def i2c_clocks(msgs) -> int:
    """SCL clocks of one combined transaction: ``msgs`` are ``(is_read, n_bytes)`` pairs."""
    return 1 + sum(1 + 9 * (1 + n) for _, n in msgs)


def serial_bytes(request_bytes: int, frame_bytes: int) -> int:
    """Bytes on the wire for one serial exchange: each packet COBS-encoded (+1) and delimited (+1)."""
    return (request_bytes + 2) + (frame_bytes + 2)


def poll_s(rig) -> float:
    """One poll's time on the wire at the rig file's clock."""
    if rig.transport == "serial":
        return 10 * serial_bytes(POLL_REQUEST_BYTES, FRAME_BYTES) / rig.serial.baud
    return i2c_clocks(((False, POLL_REQUEST_BYTES), (True, FRAME_BYTES))) / rig.i2c.bus_speed_hz


def planned_busy(rig, poll_hz: float | None = None) -> float:
    """The share of a second the link is busy with the planned polls and the thermometer's reads."""
    hz = rig.poll_hz if poll_hz is None else poll_hz
    busy = hz * poll_s(rig)
    if rig.transport == "i2c":
        busy += THERMOMETER_HZ * i2c_clocks(THERMOMETER_MSGS) / rig.i2c.bus_speed_hz
    return busy


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


def max_poll_hz(rig) -> int:
    """The fastest whole poll rate that keeps the planned share within :data:`MAX_BUSY`."""
    return int((MAX_BUSY - planned_busy(rig, 0.0)) / poll_s(rig))


def check_budget(rig, say=None):
    """The rig as it will run: unchanged when its polls fit the link with the margin; else, with ``derate = true``
    (the default), ``poll_hz`` lowered to :func:`max_poll_hz` and said on one stderr line; else a ConfigError
    naming ``poll_hz``.  A bus clock above a device's rating is a ConfigError naming ``i2c.bus_speed_hz``."""
    check_device_clocks(rig)
    busy = planned_busy(rig)
    if busy <= MAX_BUSY:
        return rig
    from dyno.errors import ConfigError

    fits = max_poll_hz(rig)
    clock = (f"{rig.serial.baud} Bd" if rig.transport == "serial" else f"{rig.i2c.bus_speed_hz} Hz SCL")
    why = (f"on {rig.transport} at {clock} each poll is {poll_s(rig) * 1e3:.1f} ms on the wire; {rig.poll_hz:g} Hz "
           f"would keep the link {100 * busy:.0f} % busy, the limit is {100 * MAX_BUSY:.0f} %")
    if rig.derate and fits >= 1:
        from dataclasses import replace

        line = f"{rig.path}: poll_hz: derated from {rig.poll_hz:g} Hz to {fits} Hz ({why}; derate = true)"
        if line not in _SAID:
            _SAID.add(line)
            (say or _stderr)(line)
        return replace(rig, poll_hz=float(fits), derated_from_hz=rig.poll_hz)
    raise ConfigError(rig.path, "poll_hz", f"at most {fits} Hz ({why}): lower poll_hz, set derate = true, or a "
                      "faster link (hardware/README.md, 'The Pi's I²C and clock stretching')")


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
        frame = read[0][1] if read and len(read[0]) > 1 and 0 < read[0][1] <= FRAME_BYTES else 0
        self.meter.add(10 * serial_bytes(written, frame) / self.serial_baud)
        return result

    def __getattr__(self, name):  # close(), the simulated bus's knobs: the bus's own
        return getattr(self.bus, name)


class TimedTransport:
    """A real firmware transport whose every transfer is charged to a :class:`LinkMeter` for the time it took
    (the transfer's own duration on ``clock``: wire, clock stretching, retries and all)."""

    def __init__(self, transport, meter: LinkMeter, clock) -> None:
        self.transport = transport
        self.meter = meter
        self.clock = clock

    def transfer(self, request: bytes, read_len: int) -> bytes:
        t0 = self.clock()
        try:
            return self.transport.transfer(request, read_len)
        finally:
            self.meter.add(self.clock() - t0)

    def write(self, request: bytes) -> None:
        t0 = self.clock()
        try:
            self.transport.write(request)
        finally:
            self.meter.add(self.clock() - t0)

    def __getattr__(self, name):  # stats, reset, close, ...: the transport's own
        return getattr(self.transport, name)


def metered_rig_link(hw, rig, clock=None):
    """(transport, thermometer read, meter) of a real rig, each transfer timed as it happens; the thermometer's
    reads are charged too where they share the firmware's I²C bus."""
    import time

    clock = clock or time.monotonic
    meter = LinkMeter(clock)
    read_c = hw.thermometer.object_c
    if rig.transport == "i2c":
        def read_c(_read=hw.thermometer.object_c):
            t0 = clock()
            try:
                return _read()
            finally:
                meter.add(clock() - t0)
    return TimedTransport(hw.transport, meter, clock), read_c, meter
