"""Protocol v2: v1's acknowledged frames plus a boot identity, the reset cause,
CRC-32C and the device's rejection counters (specified in docs/protocol.md).

Pure functions, no I/O.  Events, tags and the event layout are v1's
(:class:`dyno.protocol.v1.Event`).  Everything is big-endian.

Data frame (kind ``'D'``)::

    0      u8   version = 2
    1      u8   length L of the frame in bytes, CRC included (17..32)
    2      u8   kind: 0x44 'D' data, 0x49 'I' info
    3      u8   seq (wraps at 256; 0 is the first frame of a boot)
    4      u8   flags: bit0 RESET (no frame of this boot retired yet), bit1 MORE,
                bit2 OVERFLOW, bit3 zero, bits4..7 reset cause (MCUSR: PORF,
                EXTRF, BORF, WDRF as saved at boot)
    5-6    u16  boot_id: differs on every boot; echoed by ACK_POLL
    7-8    u16  events_dropped (ring saturation since boot or CLEAR_COUNTERS)
    9-12   u32  t0_us
    13..   events (v1 layout; the tag's bit 7, TAG_GAP, marks the first event
                after a ring saturation: events were lost just before it)
    L-4    u32  CRC-32C over bytes 0..L-5
    L..31       padding 0x00 (checked)

ACK_POLL carries the boot id: a device retires its current frame only if both
the boot id and the seq are its own, so an acknowledgement written to a device
that has since rebooted never retires a frame of the new boot.

The engine-side input torque channel (a second AD7171, issue 27) is an extension
an old host never sees: the device announces it only in answer to ``CAPS``
(a capabilities frame, kind ``'C'``), and queues its conversions (tag 4, the
layout of tag 3) only after the host enabled it with ``SET_CHANNELS`` in this
boot.  Old firmware ignores both commands (unknown op), so the host finds no
announcement and nothing changes.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from dyno.errors import FrameError
from dyno.protocol import v1
from dyno.protocol.crc import crc16, crc32c
from dyno.protocol.v1 import CH_ADC, CHANNEL_NAMES, EVENT_LEN, KIND_DATA, KIND_INFO, Event

VERSION = 2
FRAME_MAX = 32
HEADER_LEN = 13
CRC_LEN = 4
PAYLOAD_MAX = FRAME_MAX - HEADER_LEN - CRC_LEN  # 15 bytes: five Hall edges, or three + one ADC

FLAG_RESET = 0x01
FLAG_MORE = 0x02
FLAG_OVERFLOW = 0x04
FLAG_RUN = 0x08  # the Nano's run-enable output (D7) was on when the frame was built (issue 37)
FLAGS_KNOWN = FLAG_RESET | FLAG_MORE | FLAG_OVERFLOW | FLAG_RUN | 0xF0
CAUSE_SHIFT = 4

# MCUSR bits of the ATmega328P, as carried in flags bits 4..7.
CAUSE_PORF, CAUSE_EXTRF, CAUSE_BORF, CAUSE_WDRF = 0x1, 0x2, 0x4, 0x8
CAUSE_NAMES = ((CAUSE_WDRF, "watchdog"), (CAUSE_BORF, "brown-out"), (CAUSE_EXTRF, "external"),
               (CAUSE_PORF, "power-on"))

OP_POLL = v1.OP_POLL
OP_ACK_POLL = v1.OP_ACK_POLL  # u16 boot_id, u8 seq
OP_SET_DEBOUNCE = v1.OP_SET_DEBOUNCE
OP_CLEAR_COUNTERS = v1.OP_CLEAR_COUNTERS
OP_INFO = v1.OP_INFO
OP_SET_CHANNELS = 0x22  # u8 mask of optional channels to queue (CHANNEL_INPUT); the device's reply: none
OP_CAPS = 0x31          # the next read returns one capabilities frame, then data frames again
OP_SET_SUPERVISOR = 0x23  # u16 min period primary us, u16 min period secondary us, u16 heartbeat timeout ms
# u16 ms: drop the run-enable for that long and turn it back on, without latching (the kill-path probe, issue 49)
OP_PULSE_RUN_ENABLE = 0x24
PULSE_MS_MAX = 1000  # a longer (or zero) pulse is not a command: ignored, counted as a bad command ...
PULSE_LATCH = 0xFFFF  # ... but this: off and latched until the next SET_SUPERVISOR (the host's own cut)
COMMAND_ARGS = {OP_POLL: 0, OP_ACK_POLL: 3, OP_SET_DEBOUNCE: 4, OP_CLEAR_COUNTERS: 0, OP_INFO: 0,
                OP_SET_CHANNELS: 1, OP_CAPS: 0, OP_SET_SUPERVISOR: 6, OP_PULSE_RUN_ENABLE: 2}

# The optional engine-side torque channel: a second AD7171 (tag 4, tag 3's 6-byte layout).
CH_INPUT = 4
# The run-enable supervisor's changes (issue 37): tag 3's layout, code = the measured value, status = the cause.
CH_SUPERVISOR = 5
EVENT_LEN = {**EVENT_LEN, CH_INPUT: 6, CH_SUPERVISOR: 6}
CHANNEL_NAMES = {**CHANNEL_NAMES, CH_INPUT: "input", CH_SUPERVISOR: "supervisor"}
ADC_TAGS = (CH_ADC, CH_INPUT, CH_SUPERVISOR)  # (the 6-byte events: code and status)
SUP_ON, SUP_HEARTBEAT, SUP_OVERSPEED_PRIMARY, SUP_OVERSPEED_SECONDARY, SUP_PULSE = 0, 1, 2, 3, 4
SUP_CAUSE_NAMES = {SUP_ON: "on", SUP_HEARTBEAT: "heartbeat", SUP_OVERSPEED_PRIMARY: "overspeed_primary",
                   SUP_OVERSPEED_SECONDARY: "overspeed_secondary", SUP_PULSE: "pulse"}

KIND_CAPS = 0x43  # 'C'
CAPS_LEN = 20
CHANNEL_INPUT = 0x01          # SET_CHANNELS / capabilities bit: the input torque converter
CHANNEL_SUPERVISOR = 0x02     # capabilities: the run-enable output exists (channels) / is armed in this boot (enabled)
CONVERTER_NONE, CONVERTER_AD7171 = 0, 1

INFO_LEN = 32
TAG_GAP = 0x80


def cause_name(cause: int) -> str:
    """Human name of a reset cause nibble ("watchdog+external", "none" when 0)."""
    names = [n for bit, n in CAUSE_NAMES if cause & bit]
    return "+".join(names) if names else "none"


@dataclass(frozen=True, slots=True)
class DataFrame:
    seq: int
    flags: int
    boot_id: int
    events_dropped: int
    t0_us: int
    events: tuple[Event, ...] = field(default_factory=tuple)

    @property
    def reset_cause(self) -> int:
        return self.flags >> CAUSE_SHIFT


@dataclass(frozen=True, slots=True)
class InfoFrame:
    """Identity, uptime, lock-out settings and the device's rejection counters.

    The u16 counters wrap at 2**16, the u8 bus counters at 256 (rare events:
    the host takes differences).
    """

    seq: int
    flags: int
    boot_id: int
    fw_version: tuple[int, int, int]
    uptime_ms: int
    debounce_primary_us: int
    debounce_secondary_us: int
    lockout_rejected: tuple[int, int] = (0, 0)   # edges inside the lock-out, primary/secondary
    glitch_rejected: tuple[int, int] = (0, 0)    # pulses shorter than the minimum width
    twi_timeouts: int = 0                        # TWI transfers aborted by the slave timeout
    bus_errors: int = 0                          # TWI bus errors (illegal START/STOP)

    @property
    def reset_cause(self) -> int:
        return self.flags >> CAUSE_SHIFT


@dataclass(frozen=True, slots=True)
class CapsFrame:
    """What the device found at boot: its optional channels (the announcement of docs/protocol.md).

    ``channels`` is the mask of channels this boot can queue (``CHANNEL_INPUT``: a second converter
    answered at boot), ``enabled`` the mask the host set with SET_CHANNELS in this boot (0 at boot).
    """

    seq: int
    flags: int
    boot_id: int
    channels: int
    enabled: int
    input_converter: int = CONVERTER_NONE   # CONVERTER_AD7171 when fitted
    input_rate_mhz: int = 0                 # the converter's nominal rate in mHz (125 S/s: 125000)

    @property
    def has_input(self) -> bool:
        return bool(self.channels & CHANNEL_INPUT)

    @property
    def has_supervisor(self) -> bool:
        return bool(self.channels & CHANNEL_SUPERVISOR)


# --- encoding -----------------------------------------------------------------------

def fit_events(events, t0_us: int | None = None) -> int:
    """How many leading ``events`` fit one v2 frame (size and i16 time offset)."""
    return v1.fit_events(events, t0_us, payload_max=PAYLOAD_MAX, event_len=EVENT_LEN)


def _finish(body: bytes) -> bytes:
    return (body + struct.pack(">I", crc32c(body))).ljust(FRAME_MAX, b"\x00")


def encode_data_frame(seq: int, flags: int, boot_id: int, events_dropped: int, events,
                      now_us: int = 0) -> bytes:
    """Encode a data frame, padded to 32 bytes (``events`` must fit)."""
    events = tuple(events)
    t0 = events[0].t_us if events else now_us & 0xFFFFFFFF
    body = bytearray()
    for ev in events:
        dt = v1.signed32((ev.t_us - t0) & 0xFFFFFFFF)
        tag = ev.channel | (TAG_GAP if ev.gap else 0)
        if ev.channel in ADC_TAGS:
            body += struct.pack(">BhHB", tag, dt, ev.code & 0xFFFF, ev.status & 0xFF)
        else:
            body += struct.pack(">Bh", tag, dt)
    length = HEADER_LEN + len(body) + CRC_LEN
    if length > FRAME_MAX:
        raise ValueError(f"{len(events)} events need {length} bytes > {FRAME_MAX}")
    head = struct.pack(">BBBBBHHI", VERSION, length, KIND_DATA, seq & 0xFF, flags & 0xFF,
                       boot_id & 0xFFFF, events_dropped & 0xFFFF, t0)
    return _finish(head + bytes(body))


_INFO = struct.Struct(">BBBBBHBBBIHHHHHHBB")


def encode_info_frame(info: InfoFrame) -> bytes:
    major, minor, patch = info.fw_version
    body = _INFO.pack(VERSION, INFO_LEN, KIND_INFO, info.seq & 0xFF, info.flags & 0xFF,
                      info.boot_id & 0xFFFF, major, minor, patch, info.uptime_ms & 0xFFFFFFFF,
                      info.debounce_primary_us, info.debounce_secondary_us,
                      *(x & 0xFFFF for x in info.lockout_rejected), *(x & 0xFFFF for x in info.glitch_rejected),
                      info.twi_timeouts & 0xFF, info.bus_errors & 0xFF)
    return _finish(body)


_CAPS = struct.Struct(">BBBBBHBBBIxxx")


def encode_caps_frame(caps: CapsFrame) -> bytes:
    """The capabilities frame: 0-4 as the info frame, 5-6 boot_id, 7 channels, 8 enabled,
    9 input converter, 10-13 its nominal rate (mHz), 14-15 reserved zero, 16-19 CRC-32C."""
    body = _CAPS.pack(VERSION, CAPS_LEN, KIND_CAPS, caps.seq & 0xFF, caps.flags & 0xFF, caps.boot_id & 0xFFFF,
                      caps.channels & 0xFF, caps.enabled & 0xFF, caps.input_converter & 0xFF,
                      caps.input_rate_mhz & 0xFFFFFFFF)[:16]
    return _finish(body)


def encode_command(op: int, *args: int) -> bytes:
    """Commands keep v1's CRC-16 (checked byte by byte in the TWI ISR)."""
    if op not in COMMAND_ARGS:
        raise ValueError(f"unknown command op 0x{op:02x}")
    if op == OP_SET_CHANNELS:
        (mask,) = args
        body = struct.pack(">BB", op, mask & 0xFF)
    elif op == OP_SET_DEBOUNCE:
        body = struct.pack(">BHH", op, *args)
    elif op == OP_SET_SUPERVISOR:
        body = struct.pack(">BHHH", op, *(a & 0xFFFF for a in args))
    elif op == OP_PULSE_RUN_ENABLE:
        (ms,) = args
        body = struct.pack(">BH", op, ms & 0xFFFF)
    elif op == OP_ACK_POLL:
        boot_id, seq = args
        body = struct.pack(">BHB", op, boot_id & 0xFFFF, seq & 0xFF)
    else:
        if args:
            raise ValueError(f"op 0x{op:02x} takes no args")
        body = bytes([op])
    return body + struct.pack(">H", crc16(body))


def poll(ack: tuple[int, int] | None = None) -> bytes:
    """POLL, or ACK_POLL(boot_id, seq) once a frame of that boot was accepted."""
    return encode_command(OP_POLL) if ack is None else encode_command(OP_ACK_POLL, *ack)


# --- decoding -----------------------------------------------------------------------

_HEAD = struct.Struct(">BBBBBHHI")


def decode_frame(buf: bytes) -> DataFrame | InfoFrame | CapsFrame:
    """Check and decode one read; raises :class:`FrameError` with a cause (v1's causes)."""
    length = v1.check_envelope(buf, VERSION, HEADER_LEN, CRC_LEN, crc32c)
    kind = buf[2]
    flags = buf[4]
    if flags & ~FLAGS_KNOWN & 0xFF:
        raise FrameError("flags", f"0x{flags:02x}")
    if kind == KIND_INFO:
        if length != INFO_LEN:
            raise FrameError("length", f"info frame of {length} bytes")
        (_, _, _, seq, flags, boot, major, minor, patch, uptime, dbp, dbs, lp, ls, gp, gs, tmo,
         berr) = _INFO.unpack_from(buf)
        return InfoFrame(seq, flags, boot, (major, minor, patch), uptime, dbp, dbs, (lp, ls), (gp, gs),
                         tmo, berr)
    if kind == KIND_CAPS:
        if length != CAPS_LEN:
            raise FrameError("length", f"capabilities frame of {length} bytes")
        if any(buf[14:16]):
            raise FrameError("padding", "capabilities reserved bytes")
        _, _, _, seq, flags, boot, chans, enabled, conv, rate = _CAPS.unpack_from(buf[:16] + bytes(3))
        return CapsFrame(seq, flags, boot, chans, enabled, conv, rate)
    if kind != KIND_DATA:
        raise FrameError("kind", f"0x{kind:02x}")
    _, _, _, seq, flags, boot, dropped, t0 = _HEAD.unpack_from(buf)
    events = []
    i, end = HEADER_LEN, length - CRC_LEN
    while i < end:
        raw_tag = buf[i]
        tag = raw_tag & ~TAG_GAP
        gap = bool(raw_tag & TAG_GAP)
        size = EVENT_LEN.get(tag)
        if size is None:
            raise FrameError("event_tag", f"0x{raw_tag:02x} at byte {i}")
        if i + size > end:
            raise FrameError("event_length", f"event at byte {i} overruns")
        dt = buf[i + 1] << 8 | buf[i + 2]
        if dt >= 0x8000:
            dt -= 0x10000
        t = (t0 + dt) & 0xFFFFFFFF
        if tag in ADC_TAGS:
            events.append(Event(tag, t, buf[i + 3] << 8 | buf[i + 4], buf[i + 5], gap))
        else:
            events.append(Event(tag, t, gap=gap))
        i += size
    return DataFrame(seq, flags, boot, dropped, t0, tuple(events))


def decode_command(buf: bytes) -> v1.Command:
    """Check and decode a host command (the device's side, mirrored for the sim)."""
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
        return v1.Command(op, struct.unpack(">HH", buf[1:5]))
    if op == OP_ACK_POLL:
        return v1.Command(op, struct.unpack(">HB", buf[1:4]))
    if op == OP_SET_CHANNELS:
        return v1.Command(op, (buf[1],))
    if op == OP_SET_SUPERVISOR:
        return v1.Command(op, struct.unpack(">HHH", buf[1:7]))
    if op == OP_PULSE_RUN_ENABLE:
        return v1.Command(op, struct.unpack(">H", buf[1:3]))
    return v1.Command(op, ())


def min_period_us(limit_rpm: float | None) -> int:
    """The shortest Hall period (one pulse per revolution) below an over-speed limit: int(60e6 / rpm),
    0 (not checked) without a limit; at most 65535 (a limit below 916 rpm is checked at 916)."""
    if not limit_rpm or limit_rpm <= 0:
        return 0
    return min(0xFFFF, int(60e6 / float(limit_rpm)))


def supervisor_command(limit_primary_rpm: float | None, limit_secondary_rpm: float | None,
                       timeout_s: float) -> bytes:
    """SET_SUPERVISOR: arm (or re-arm) the Nano's run-enable with the rig file's limits (docs/protocol.md).

    ``timeout_s`` is the heartbeat timeout, sent in whole ms (1 ... 65535)."""
    timeout_ms = max(1, min(0xFFFF, round(float(timeout_s) * 1000.0)))
    return encode_command(OP_SET_SUPERVISOR, min_period_us(limit_primary_rpm), min_period_us(limit_secondary_rpm),
                          timeout_ms)


def pulse_command(ms: int) -> bytes:
    """PULSE_RUN_ENABLE: the Nano drops its run-enable for ``ms`` (1 ... PULSE_MS_MAX) and turns it back on,
    unlatched, if it was on (docs/protocol.md; the kill-path probe, issue 49); ``PULSE_LATCH``: off, latched."""
    if not (1 <= int(ms) <= PULSE_MS_MAX or int(ms) == PULSE_LATCH):
        raise ValueError(f"pulse of {ms} ms: 1 ... {PULSE_MS_MAX}")
    return encode_command(OP_PULSE_RUN_ENABLE, int(ms))
