"""MLX90614 rotor IR thermometer over SMBus, with its PEC checked.

The thesis code (App. H ``read_temp``) used ``read_word_data`` and turned any
error into 0 K (-273 °C): a dead sensor read as a cold rotor.  Here a read is
``write [cmd]``, repeated start, ``read 3`` (LSB, MSB, PEC) in one
``i2c_rdwr``; the PEC (SMBus CRC-8, poly 0x07, over addr+W, cmd, addr+R, LSB,
MSB) and the error flag (bit 15) are checked and failures raise.

Works on any SMBus-like object with ``i2c_rdwr`` (smbus2, the simulated bus).
"""

from __future__ import annotations

from dyno.errors import TransportError

CMD_AMBIENT = 0x06  # RAM: Ta
CMD_OBJECT = 0x07  # RAM: Tobj1, the rotor
KELVIN_PER_LSB = 0.02
ERROR_FLAG = 0x8000


class ThermometerError(TransportError):
    """A thermometer read failed; ``cause`` in {"pec", "error_flag", "nack", "timeout", "io"}."""

    def __init__(self, cause: str, detail: str = "") -> None:
        self.cause = cause
        super().__init__(f"MLX90614 {cause}: {detail}" if detail else f"MLX90614 {cause}")


def smbus_pec(data: bytes) -> int:
    """SMBus PEC: CRC-8, polynomial x^8+x^2+x+1 (0x07), init 0, no reflection.

    Bitwise: 5 bytes per read, and binascii has no CRC-8.
    """
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def raw_to_celsius(raw: int) -> float:
    return raw * KELVIN_PER_LSB - 273.15


class MLX90614:
    def __init__(self, bus, address: int = 0x5A) -> None:
        from smbus2 import i2c_msg  # the only place smbus2 types appear here

        self._msg = i2c_msg
        self.bus = bus
        self.address = address
        self.errors: dict[str, int] = {}

    def read_raw(self, command: int) -> int:
        """One checked SMBus read-word with PEC; returns the 15-bit value."""
        a = self.address
        wr = self._msg.write(a, [command])
        rd = self._msg.read(a, 3)
        try:
            self.bus.i2c_rdwr(wr, rd)
        except OSError as exc:
            from dyno.transports.base import ERRNO_CAUSE

            self._fail(ERRNO_CAUSE.get(exc.errno, "io"), str(exc))
        lsb, msb, pec = bytes(rd)[:3]
        want = smbus_pec(bytes([a << 1, command, (a << 1) | 1, lsb, msb]))
        if pec != want:
            self._fail("pec", f"got 0x{pec:02X}, expected 0x{want:02X}")
        raw = msb << 8 | lsb
        if raw & ERROR_FLAG:
            self._fail("error_flag", f"raw 0x{raw:04X}")
        return raw

    def _fail(self, cause: str, detail: str):
        self.errors[cause] = self.errors.get(cause, 0) + 1
        raise ThermometerError(cause, detail)

    def object_c(self) -> float:
        """Rotor (object 1) temperature, °C."""
        return raw_to_celsius(self.read_raw(CMD_OBJECT))

    def ambient_c(self) -> float:
        """Sensor die (ambient) temperature, °C."""
        return raw_to_celsius(self.read_raw(CMD_AMBIENT))
