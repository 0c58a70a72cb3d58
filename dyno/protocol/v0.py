"""Protocol v0: the thesis rig's legacy 20-byte frame (read-only, no commands).

::

    0-1   u16 primary rpm        2-5   u32 primary edge time (micros())
    6-7   u16 secondary rpm      8-11  u32 secondary edge time
    12-13 u16 ADC code           14-17 u32 ADC conversion time
    18-19 u16 sum of bytes 0..17 (mod 2**16)

All big-endian.  The legacy firmware overwrites each channel's slot with its
latest value, so consecutive reads repeat until something new happens; the
host turns *new timestamps* into events.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from dyno.errors import FrameError
from dyno.protocol.crc import sum16

FRAME_LEN = 20
_FMT = struct.Struct(">HIHIHIH")


@dataclass(frozen=True, slots=True)
class LegacyFrame:
    rpm_primary: int
    t_primary_us: int
    rpm_secondary: int
    t_secondary_us: int
    adc_code: int
    t_adc_us: int


def encode_legacy_frame(f: LegacyFrame) -> bytes:
    body = struct.pack(">HIHIHI", f.rpm_primary, f.t_primary_us, f.rpm_secondary,
                       f.t_secondary_us, f.adc_code, f.t_adc_us)
    return body + struct.pack(">H", sum16(body))


def decode_legacy_frame(buf: bytes) -> LegacyFrame:
    """Check and decode a 20-byte legacy frame; raises :class:`FrameError`."""
    if len(buf) < FRAME_LEN:
        raise FrameError("short", f"{len(buf)} bytes")
    buf = bytes(buf[:FRAME_LEN])
    if not any(buf):
        raise FrameError("all_zero")
    if buf.count(0xFF) == FRAME_LEN:
        raise FrameError("all_ff")
    rp, tp, rs, ts, adc, ta, check = _FMT.unpack(buf)
    if sum16(buf[:18]) != check:
        raise FrameError("checksum")
    return LegacyFrame(rp, tp, rs, ts, adc, ta)
