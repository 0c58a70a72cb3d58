"""Protocol v1: the frames our firmware serves (specified in docs/protocol.md).

Pure functions, no I/O.  A *frame* is what one read returns (at most 32 bytes,
the Nano's Wire buffer); a *command* is what the host writes.  Everything is
big-endian.

Data frame (kind ``'D'``)::

    0     u8   version = 1
    1     u8   length L of the frame in bytes, CRC included (13..32)
    2     u8   kind: 0x44 'D' data, 0x49 'I' info
    3     u8   seq: frame sequence number (wraps at 256)
    4     u8   flags: bit0 RESET (first frame since boot), bit1 MORE (events
               still queued), bit2 OVERFLOW (ring overflowed since last clear);
               bits 3..7 zero
    5-6   u16  events_dropped: cumulative ring-overflow count (wraps)
    7-10  u32  t0_us: device time of the first event (device "now" if none)
    11..  events, each: u8 tag, i16 dt_us (from t0), then for tag 3 (ADC)
               u16 code and u8 AD7171 status bits
    L-2   u16  CRC-16/CCITT-FALSE over bytes 0..L-3
    L..31      padding 0x00 (checked)

Tags: 1 primary Hall edge, 2 secondary Hall edge, 3 ADC conversion.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from dyno.errors import FrameError
from dyno.protocol.crc import crc16

VERSION = 1
FRAME_MAX = 32  # the Nano's Wire (TWI) buffer: one I2C read never exceeds it
HEADER_LEN = 11
CRC_LEN = 2
PAYLOAD_MAX = FRAME_MAX - HEADER_LEN - CRC_LEN  # 19 bytes of events

KIND_DATA = 0x44  # 'D'
KIND_INFO = 0x49  # 'I'

FLAG_RESET = 0x01
FLAG_MORE = 0x02
FLAG_OVERFLOW = 0x04
FLAGS_KNOWN = FLAG_RESET | FLAG_MORE | FLAG_OVERFLOW

CH_PRIMARY = 1
CH_SECONDARY = 2
CH_ADC = 3
CHANNEL_NAMES = {CH_PRIMARY: "primary", CH_SECONDARY: "secondary", CH_ADC: "adc"}
EVENT_LEN = {CH_PRIMARY: 3, CH_SECONDARY: 3, CH_ADC: 6}

# AD7171 status bits as clocked out after the 16 data bits (MSB first).  The
# thesis firmware took the third status bit as the error flag.
ADC_STATUS_ERR = 0x20

DT_MIN, DT_MAX = -32768, 32767

# Commands (host -> device): [op, args..., crc16 hi, lo]
OP_POLL = 0x10  # serve the current frame, retire nothing
OP_ACK_POLL = 0x11  # retire frame `seq` if it is current and was sent; serve the next
OP_SET_DEBOUNCE = 0x20  # u16 primary_us, u16 secondary_us
OP_CLEAR_COUNTERS = 0x21  # zero events_dropped and the OVERFLOW flag
OP_INFO = 0x30  # the next read returns one info frame
COMMAND_ARGS = {OP_POLL: 0, OP_ACK_POLL: 1, OP_SET_DEBOUNCE: 4, OP_CLEAR_COUNTERS: 0, OP_INFO: 0}

INFO_LEN = 22


@dataclass(frozen=True, slots=True)
class Event:
    """One timestamped event as the device saw it (raw u32 device time)."""

    channel: int
    t_us: int
    code: int = 0
    status: int = 0
    gap: bool = False  # v2: events were lost (ring saturated) just before this one


@dataclass(frozen=True, slots=True)
class DataFrame:
    seq: int
    flags: int
    events_dropped: int
    t0_us: int
    events: tuple[Event, ...] = field(default_factory=tuple)


@dataclass(frozen=True, slots=True)
class InfoFrame:
    seq: int
    flags: int
    fw_version: tuple[int, int, int]
    boot_count: int
    uptime_ms: int
    debounce_primary_us: int
    debounce_secondary_us: int


@dataclass(frozen=True, slots=True)
class Command:
    op: int
    args: tuple[int, ...] = ()


# --- encoding (used by the simulated device, the vectors and the tests) -------

def event_size(ev: Event) -> int:
    return EVENT_LEN[ev.channel]


def fit_events(events, t0_us: int | None = None, payload_max: int = PAYLOAD_MAX, event_len=None) -> int:
    """How many leading ``events`` fit one frame (size and i16 time offset; ``event_len``: bytes per tag)."""
    event_len = EVENT_LEN if event_len is None else event_len
    used = n = 0
    for ev in events:
        if t0_us is None:
            t0_us = ev.t_us
        dt = signed32((ev.t_us - t0_us) & 0xFFFFFFFF)
        size = event_len[ev.channel]
        if used + size > payload_max or not DT_MIN <= dt <= DT_MAX:
            break
        used += size
        n += 1
    return n


def encode_data_frame(seq: int, flags: int, events_dropped: int, events, now_us: int = 0) -> bytes:
    """Encode a data frame, padded to :data:`FRAME_MAX` bytes.

    ``events`` must all fit (see :func:`fit_events`); ``now_us`` is t0 when
    there are none.
    """
    events = tuple(events)
    t0 = events[0].t_us if events else now_us & 0xFFFFFFFF
    body = bytearray()
    for ev in events:
        dt = signed32((ev.t_us - t0) & 0xFFFFFFFF)
        if ev.channel == CH_ADC:
            body += struct.pack(">BhHB", ev.channel, dt, ev.code & 0xFFFF, ev.status & 0xFF)
        else:
            body += struct.pack(">Bh", ev.channel, dt)
    length = HEADER_LEN + len(body) + CRC_LEN
    if length > FRAME_MAX:
        raise ValueError(f"{len(events)} events need {length} bytes > {FRAME_MAX}")
    head = struct.pack(">BBBBBHI", VERSION, length, KIND_DATA, seq & 0xFF, flags & 0xFF,
                       events_dropped & 0xFFFF, t0)
    frame = head + bytes(body)
    return (frame + struct.pack(">H", crc16(frame))).ljust(FRAME_MAX, b"\x00")


def encode_info_frame(info: InfoFrame) -> bytes:
    major, minor, patch = info.fw_version
    head = struct.pack(">BBBBBBBBHIHH", VERSION, INFO_LEN, KIND_INFO, info.seq & 0xFF,
                       info.flags & 0xFF, major, minor, patch, info.boot_count & 0xFFFF,
                       info.uptime_ms & 0xFFFFFFFF, info.debounce_primary_us,
                       info.debounce_secondary_us) + b"\x00\x00"  # bytes 18-19 reserved, zero
    return (head + struct.pack(">H", crc16(head))).ljust(FRAME_MAX, b"\x00")


def encode_command(op: int, *args: int) -> bytes:
    if op not in COMMAND_ARGS:
        raise ValueError(f"unknown command op 0x{op:02x}")
    if op == OP_SET_DEBOUNCE:
        body = struct.pack(">BHH", op, *args)
    else:
        if len(args) != COMMAND_ARGS[op]:
            raise ValueError(f"op 0x{op:02x} takes {COMMAND_ARGS[op]} byte args")
        body = bytes([op, *args])
    return body + struct.pack(">H", crc16(body))


def poll(ack_seq: int | None = None) -> bytes:
    """The poll command: plain (first read, or after a bad read) or acknowledging."""
    return encode_command(OP_POLL) if ack_seq is None else encode_command(OP_ACK_POLL, ack_seq & 0xFF)


# --- decoding ------------------------------------------------------------------

_HEAD = struct.Struct(">BBBBBHI")
_INFO = struct.Struct(">BBBBBBBBHIHH")


def check_envelope(buf: bytes, version: int, header_len: int, crc_len: int, crc) -> int:
    """The checks every framed version shares (v1 and v2): returns the frame's length.

    A read that is too short, all 0x00 (a released bus) or all 0xFF (nobody answered),
    of another version, of an impossible length, failing its check (``crc`` over the
    bytes before it, big-endian), or with non-zero padding raises :class:`FrameError`.
    """
    n = len(buf)
    if n < header_len + crc_len:
        raise FrameError("short", f"{n} bytes")
    if not any(buf):
        raise FrameError("all_zero")
    if buf.count(0xFF) == n:
        raise FrameError("all_ff")
    if buf[0] != version:
        raise FrameError("version", f"got {buf[0]}")
    length = buf[1]
    if not header_len + crc_len <= length <= min(n, FRAME_MAX):
        raise FrameError("length", f"{length} with {n} bytes read")
    if crc(buf[: length - crc_len]) != int.from_bytes(buf[length - crc_len: length], "big"):
        raise FrameError("crc")
    if any(buf[length:]):
        raise FrameError("padding")
    return length


def decode_frame(buf: bytes) -> DataFrame | InfoFrame:
    """Check and decode one read.  Raises :class:`FrameError` with a cause.

    Causes: ``short``, ``all_zero``, ``all_ff``, ``version``, ``length``,
    ``crc``, ``kind``, ``flags``, ``event_tag``, ``event_length``, ``padding``.
    """
    length = check_envelope(buf, VERSION, HEADER_LEN, CRC_LEN, crc16)
    kind = buf[2]
    if kind == KIND_INFO:
        if length != INFO_LEN:
            raise FrameError("length", f"info frame of {length} bytes")
        (_, _, _, seq, flags, major, minor, patch, boots, uptime, dbp, dbs) = _INFO.unpack_from(buf)
        return InfoFrame(seq, flags, (major, minor, patch), boots, uptime, dbp, dbs)
    if kind != KIND_DATA:
        raise FrameError("kind", f"0x{kind:02x}")
    _, _, _, seq, flags, dropped, t0 = _HEAD.unpack_from(buf)
    if flags & ~FLAGS_KNOWN:
        raise FrameError("flags", f"0x{flags:02x}")
    events = []
    i, end = HEADER_LEN, length - CRC_LEN
    while i < end:
        tag = buf[i]
        size = EVENT_LEN.get(tag)
        if size is None:
            raise FrameError("event_tag", f"0x{tag:02x} at byte {i}")
        if i + size > end:
            raise FrameError("event_length", f"event at byte {i} overruns")
        dt = (buf[i + 1] << 8 | buf[i + 2])
        if dt >= 0x8000:
            dt -= 0x10000
        t = (t0 + dt) & 0xFFFFFFFF
        if tag == CH_ADC:
            events.append(Event(tag, t, buf[i + 3] << 8 | buf[i + 4], buf[i + 5]))
        else:
            events.append(Event(tag, t))
        i += size
    return DataFrame(seq, flags, dropped, t0, tuple(events))


def decode_command(buf: bytes) -> Command:
    """Check and decode a host command (the firmware's side, mirrored for the sim)."""
    if len(buf) < 3:
        raise FrameError("short", f"command of {len(buf)} bytes")
    op = buf[0]
    if op not in COMMAND_ARGS:
        raise FrameError("op", f"0x{op:02x}")
    size = 1 + COMMAND_ARGS[op] + 2
    if len(buf) != size:
        raise FrameError("length", f"command 0x{op:02x} of {len(buf)} bytes, expected {size}")
    if crc16(buf[:-2]) != (buf[-2] << 8 | buf[-1]):
        raise FrameError("crc", "command")
    if op == OP_SET_DEBOUNCE:
        return Command(op, struct.unpack(">HH", buf[1:5]))
    return Command(op, tuple(buf[1:-2]))


def signed32(x: int) -> int:
    return x - 0x100000000 if x & 0x80000000 else x
