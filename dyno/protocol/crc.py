"""Integrity checks used on the wire.

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
