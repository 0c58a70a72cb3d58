"""The firmware over USB serial (pyserial): v2/v1 frames as COBS packets ending in 0x00.

Framing (docs/protocol.md, "v1 and v2 over USB serial"): each command and each frame
is COBS-encoded and terminated by one 0x00.  COBS output has no zero byte, so
a 0x00 always ends a packet and a receiver resynchronises at the next 0x00.

Garbage glued to the front of a packet (line noise, a reset mid-packet, a
bootloader banner) is not separated from it by a 0x00.  :class:`CobsDeframer`
therefore checks each packet with a validator (default: a v2 or v1 frame, whose
length byte and CRC-32C / CRC-16 must agree) and, if the whole packet fails, tries its
suffixes, so no complete frame is lost to garbage in front of it.

Over serial, frames come without padding; the transport pads them to the
asked length so the same decoder (which checks padding) reads both links.
"""

from __future__ import annotations

import binascii
from collections import Counter, deque

from dyno.clock import MonotonicClock
from dyno.protocol.crc import crc32c
from dyno.transports.base import Transport, TransportFault

DELIMITER = b"\x00"
FRAME_MAX = 32  # v1 frames are at most the Nano's 32-byte Wire buffer
# COBS adds one byte per 254 (and one minimum): a frame never encodes longer than this.
ENCODED_MAX = FRAME_MAX + 1 + FRAME_MAX // 254


# The `cobs` PyPI package is not installed on the rig image and the codec is
# tiny, so it is written out here (Cheshire & Baker 1999).

def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (no delimiter added)."""
    out = bytearray()
    block = bytearray()
    for byte in data:
        if byte == 0:
            out.append(len(block) + 1)
            out += block
            block.clear()
        else:
            block.append(byte)
            if len(block) == 254:  # a full block: code 0xFF means "254 bytes, no zero follows"
                out.append(255)
                out += block
                block.clear()
    out.append(len(block) + 1)
    out += block
    return bytes(out)


def cobs_decode(packet: bytes) -> bytes:
    """Decode one COBS packet (without its 0x00).  Raises ValueError if malformed."""
    out = bytearray()
    i, n = 0, len(packet)
    while i < n:
        code = packet[i]
        if code == 0:
            raise ValueError("zero byte inside a COBS packet")
        end = i + code
        if end > n:
            raise ValueError("COBS code runs past the end of the packet")
        block = packet[i + 1:end]
        if 0 in block:
            raise ValueError("zero byte inside a COBS packet")
        out += block
        i = end
        if code != 255 and i < n:
            out.append(0)
    return bytes(out)


def is_v1_frame(data: bytes) -> bool:
    """Length byte matches and CRC-16/CCITT-FALSE checks (docs/protocol.md)."""
    n = len(data)
    if n < 13 or n > FRAME_MAX or data[1] != n:
        return False
    return binascii.crc_hqx(data[:-2], 0xFFFF) == (data[-2] << 8 | data[-1])


def is_v2_frame(data: bytes) -> bool:
    """Length byte matches and CRC-32C checks (docs/protocol.md, v2)."""
    n = len(data)
    if n < 17 or n > FRAME_MAX or data[1] != n:
        return False
    return crc32c(data[:-4]) == int.from_bytes(data[-4:], "big")


def is_frame(data: bytes) -> bool:
    """A v2 or v1 packet: the session above decides which version it wants (and refuses the other)."""
    return is_v2_frame(data) if data[:1] == b"\x02" else is_v1_frame(data)


class CobsDeframer:
    """Byte stream in, decoded packets out; resynchronises after garbage.

    ``validate(decoded) -> bool`` (default :func:`is_frame`; ``None`` accepts
    any well-formed COBS packet).  Counters: ``packets``, ``garbage_bytes``,
    ``bad_packets`` (delimited chunks with no valid packet in them).
    """

    def __init__(self, validate=is_frame, max_encoded: int = ENCODED_MAX) -> None:
        self.validate = validate
        self.max_encoded = max_encoded
        self._buf = bytearray()
        self.stats: Counter = Counter()

    def feed(self, data: bytes) -> list[bytes]:
        out = []
        for chunk_end in _split_keep(data):
            piece, ended = chunk_end
            self._buf += piece
            if not ended:
                # No delimiter yet: keep at most one maximal packet's worth, since
                # anything older can only be garbage.
                if self.validate is not None and len(self._buf) > self.max_encoded:
                    drop = len(self._buf) - self.max_encoded
                    self.stats["garbage_bytes"] += drop
                    del self._buf[:drop]
                continue
            chunk = bytes(self._buf)
            self._buf.clear()
            if chunk:
                pkt = self._extract(chunk)
                if pkt is not None:
                    out.append(pkt)
        return out

    def _extract(self, chunk: bytes) -> bytes | None:
        start_min = max(0, len(chunk) - self.max_encoded) if self.validate is not None else 0
        starts = range(start_min, len(chunk)) if self.validate is not None else (0,)
        for start in starts:  # longest suffix first: the whole chunk when it is clean
            try:
                pkt = cobs_decode(chunk[start:])
            except ValueError:
                continue
            if self.validate is None or self.validate(pkt):
                self.stats["packets"] += 1
                self.stats["garbage_bytes"] += start
                return pkt
        self.stats["bad_packets"] += 1
        self.stats["garbage_bytes"] += len(chunk)
        return None


def _split_keep(data: bytes):
    """Yield (piece, ended_by_delimiter) over ``data``."""
    start = 0
    while True:
        i = data.find(0, start)
        if i < 0:
            if start < len(data):
                yield data[start:], False
            return
        yield data[start:i], True
        start = i + 1


class SerialTransport(Transport):
    """One request packet out, one frame packet back, on a pyserial-like port.

    ``port`` needs ``write``, ``read(n)``, ``in_waiting`` and a settable
    ``timeout`` (pyserial ``Serial`` or ``serial_for_url("loop://")``).

    Packets that were already waiting before a request is sent are late
    answers to a request whose transfer already timed out; they are dropped
    (counted as ``late``) so answers never lag requests.  Nothing is lost by
    that: an unacknowledged v1 frame is served again on the next poll.
    """

    name = "serial"

    def __init__(self, port, *, timeout_s: float = 0.05, clock=None, validate=is_frame) -> None:
        super().__init__()
        self.port = port
        self.timeout_s = float(timeout_s)
        self.clock = clock or MonotonicClock()
        self.deframer = CobsDeframer(validate)
        self._packets: deque[bytes] = deque()
        self.late = 0

    def _pump(self, block_s: float) -> None:
        """Read what is there (waiting up to ``block_s`` for the first byte)."""
        port = self.port
        port.timeout = max(0.0, block_s)
        first = port.read(1)
        if not first:
            return
        rest = port.read(port.in_waiting) if port.in_waiting else b""
        self._packets.extend(self.deframer.feed(bytes(first) + bytes(rest)))

    def _transfer(self, request: bytes, read_len: int) -> bytes:
        if read_len:
            while self.port.in_waiting:
                self._pump(0.0)
            self.late += len(self._packets)
            self._packets.clear()
        if self.meter is None:
            return self._exchange(request, read_len)
        t0 = self._meter_now()
        try:
            return self._exchange(request, read_len)
        finally:
            self.meter.add(self._meter_now() - t0)

    def _exchange(self, request: bytes, read_len: int) -> bytes:
        """The request's packet out, its frame back (the link's time: what the meter charges)."""
        if request:
            self.port.write(cobs_encode(request) + DELIMITER)
            flush = getattr(self.port, "flush", None)
            if flush:
                flush()
        if not read_len:
            return b""
        deadline = self.clock.now() + self.timeout_s
        while not self._packets:
            remaining = deadline - self.clock.now()
            if remaining <= 0:
                raise TransportFault("timeout", f"no frame within {self.timeout_s * 1e3:.0f} ms")
            self._pump(remaining)
        pkt = self._packets.popleft()
        if len(pkt) > read_len:
            raise TransportFault("io", f"{len(pkt)}-byte packet for a {read_len}-byte read")
        return pkt + bytes(read_len - len(pkt))

    def receive(self) -> list[bytes]:
        """Every complete packet received so far (no request): for streaming use and tests."""
        while self.port.in_waiting:
            self._pump(0.0)
        out = list(self._packets)
        self._packets.clear()
        return out

    def close(self) -> None:
        close = getattr(self.port, "close", None)
        if close:
            close()


#: after opening, nothing is sent before this long: Optiboot listens ~1 s after the reset and would take the bytes
#: for an upload (STK500 commands: a stray 0x64 is "program a page")
BOOT_WINDOW_S = 1.2
#: ... and not before the line has been this quiet: a bootloader that talks during its window is let finish
BOOT_QUIET_GAP_S = 0.15
#: then the first answer is asked for this often until ``serial.boot_timeout_s``
BOOT_POLL_S = 0.1


def open_serial(config, *, port=None, clock=None, wait_boot: bool = True) -> SerialTransport:
    """The firmware transport over USB serial for a RigConfig (8N1, ``config.serial``), ready to use.

    Opening a Nano's port pulses its DTR line, which resets it: Optiboot listens for an upload for about a
    second, then the sketch starts.  So this sends nothing for :data:`BOOT_WINDOW_S` and until the line has been
    quiet :data:`BOOT_QUIET_GAP_S` (what the bootloader said is dropped), then asks for a frame every
    :data:`BOOT_POLL_S` until one answers or ``serial.boot_timeout_s`` has passed since the open (one line
    naming the port and what to check).  ``wait_boot=False``: the port as opened (a Nano whose auto-reset is
    cut answers at once).  The FTDI chip's 16 ms latency timer (~60 answers a second at most) is set low where
    the driver allows it (docs/install-pi.md has the udev rule that does it for good).
    """
    clock = clock or MonotonicClock()
    if port is None:
        import serial  # pyserial, imported lazily so the I2C-only rig never needs it

        try:
            port = serial.serial_for_url(config.serial.port, baudrate=config.serial.baud,
                                         timeout=config.serial.timeout_s)
        except serial.SerialException as exc:
            raise TransportFault("io", f"{config.serial.port}: {exc}") from exc
        low_latency = getattr(port, "set_low_latency_mode", None)
        if low_latency is not None:
            try:
                low_latency(True)  # FTDI: the latency timer to 1 ms (ASYNC_LOW_LATENCY)
            except (OSError, ValueError, AttributeError):  # not every driver has it (the CH340's needs none)
                pass
    transport = SerialTransport(port, timeout_s=config.serial.timeout_s, clock=clock)
    if wait_boot:
        wait_for_firmware(transport, config, clock)
    return transport


def wait_for_firmware(transport: SerialTransport, config, clock) -> float:
    """Wait for the first valid frame after the port's open (its reset); returns the seconds it took."""
    from dyno.protocol import v1, v2

    proto = v2 if config.protocol == "v2" else v1
    ask = proto.encode_command(proto.OP_INFO)
    t0 = clock.now()
    deadline = t0 + config.serial.boot_timeout_s
    drain_bootloader(transport, clock, until_s=t0 + BOOT_WINDOW_S, deadline_s=deadline)
    while True:
        try:
            transport.transfer(ask, FRAME_MAX)
            return clock.now() - t0
        except TransportFault:
            pass
        if clock.now() >= deadline:
            raise TransportFault("timeout", f"{config.serial.port}: no frame within {config.serial.boot_timeout_s:g} s "
                                 "of opening the port (it resets the Nano; its bootloader listens ~1 s): check the "
                                 "USB cable, the firmware is flashed, and protocol/baud in rig.toml")
        clock.sleep(BOOT_POLL_S)


def drain_bootloader(transport: SerialTransport, clock, *, until_s: float, deadline_s: float) -> int:
    """Send nothing until ``until_s`` and until the line has been quiet :data:`BOOT_QUIET_GAP_S` (at most until
    ``deadline_s``); whatever the bootloader sent meanwhile is dropped.  Returns the bytes dropped."""
    port = transport.port
    dropped = 0
    last_byte_s = clock.now()
    while True:
        now = clock.now()
        if now >= deadline_s or (now >= until_s and now - last_byte_s >= BOOT_QUIET_GAP_S):
            break
        port.timeout = min(BOOT_POLL_S, max(0.0, deadline_s - now))
        got = port.read(max(1, port.in_waiting))
        if got:
            dropped += len(got)
            last_byte_s = clock.now()
    transport.deframer = CobsDeframer(transport.deframer.validate)  # no half packet of the banner kept
    transport._packets.clear()
    return dropped
