"""Integrity checks used on the wire (v2 frames: CRC-32C; v1 frames and all commands: CRC-16).

CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor):
exactly what the stdlib's :func:`binascii.crc_hqx` computes with ``value=0xFFFF``,
and a few lines of table-less C on the AVR.  Check value: ``crc16(b"123456789")
== 0x29B1``.
"""

from binascii import crc_hqx


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data``."""
    return crc_hqx(data, 0xFFFF)


def sum16(data: bytes) -> int:
    """The legacy (v0) checksum: the plain sum of the bytes, modulo 2**16."""
    return sum(data) & 0xFFFF


def _crc32c_table() -> tuple[int, ...]:
    # Reflected Castagnoli polynomial 0x1EDC6F41 (bit-reversed: 0x82F63B78).
    out = []
    for b in range(256):
        c = b
        for _ in range(8):
            c = (c >> 1) ^ 0x82F63B78 if c & 1 else c >> 1
        out.append(c)
    return tuple(out)


_CRC32C = _crc32c_table()


def crc32c(data: bytes) -> int:
    """CRC-32C (Castagnoli; iSCSI, ext4): reflected, init and final xor 0xFFFFFFFF.

    Check value ``crc32c(b"123456789") == 0xE3069283``.  Hamming distance 6 up to
    5243 data bits, so every pattern of up to 5 flipped bits in a 32-byte frame is
    caught; anything heavier passes with probability ~2**-32 (docs/protocol.md).
    """
    c = 0xFFFFFFFF
    t = _CRC32C
    for b in data:
        c = t[(c ^ b) & 0xFF] ^ (c >> 8)
    return c ^ 0xFFFFFFFF
