"""Bosch BME280 ambient sensor (intake air temperature, station pressure, humidity) over I²C.

Written from the data sheet (BST-BME280-DS002, §4.2 trimming registers, §5.4 memory map, §8.1
floating-point compensation) rather than taken from a package: the maintained drivers either talk
another I/O layer (pimoroni's needs ``i2cdevice``; Adafruit's needs Blinka) or are no longer kept
(RPi.bme280, last release 2020), and none speaks the one call this project's buses share,
``i2c_rdwr`` (smbus2 on the rig, :class:`dyno.sim.bus.SimSMBus` in the simulator).  The compensation
is the data sheet's formulas and nothing more; :func:`compensate` is pure, so the simulated chip
inverts the very same functions.

One read is a *forced* conversion (oversampling ×1 on each channel: ~8 ms, 0.005 °C / 0.18 Pa
resolution, far below the sensor's ±1 °C / ±1 hPa / ±3 %RH absolute accuracy).
"""

from __future__ import annotations

import struct
import time

from dyno.errors import TransportError

CHIP_ID = 0x60  # (a BMP280 says 0x58: no humidity)
REG_ID, REG_RESET, REG_CTRL_HUM, REG_STATUS, REG_CTRL_MEAS, REG_DATA = 0xD0, 0xE0, 0xF2, 0xF3, 0xF4, 0xF7
REG_CALIB_TP, REG_CALIB_H1, REG_CALIB_H = 0x88, 0xA1, 0xE1
CTRL_HUM_X1 = 0x01
CTRL_MEAS_FORCED_X1 = 0b001_001_01  # osrs_t ×1, osrs_p ×1, forced mode
STATUS_MEASURING = 0x08
DEFAULT_ADDRESS = 0x76  # SDO to GND (0x77 with SDO to VDDIO)


class AmbientSensorError(TransportError):
    """The ambient sensor did not answer, or answered as something else."""


def parse_trimming(tp: bytes, h1: int, h: bytes) -> dict:
    """The trimming parameters from registers 0x88..0x9F (24 bytes), 0xA1 and 0xE1..0xE7 (7 bytes)."""
    t1, t2, t3, p1, p2, p3, p4, p5, p6, p7, p8, p9 = struct.unpack("<HhhHhhhhhhhh", tp[:24])
    h2, h3 = struct.unpack("<hB", h[0:3])
    h4 = (h[3] << 4) | (h[4] & 0x0F)
    h5 = (h[5] << 4) | (h[4] >> 4)
    h4 = h4 - 4096 if h4 & 0x800 else h4  # 12-bit signed
    h5 = h5 - 4096 if h5 & 0x800 else h5
    h6 = struct.unpack("<b", h[6:7])[0]
    return {"T": (t1, t2, t3), "P": (p1, p2, p3, p4, p5, p6, p7, p8, p9), "H": (h1, h2, h3, h4, h5, h6)}


def pack_trimming(trim: dict) -> tuple[bytes, int, bytes]:
    """The inverse of :func:`parse_trimming` (the simulated chip's registers)."""
    tp = struct.pack("<HhhHhhhhhhhh", *trim["T"], *trim["P"])
    h1, h2, h3, h4, h5, h6 = trim["H"]
    h4u, h5u = h4 & 0xFFF, h5 & 0xFFF
    h = struct.pack("<hB", h2, h3) + bytes([h4u >> 4, (h4u & 0x0F) | ((h5u & 0x0F) << 4), h5u >> 4]) + \
        struct.pack("<b", h6)
    return tp, h1, h


def compensate_t(adc_t: int, trim: dict) -> tuple[float, float]:
    """(temperature °C, t_fine) from the 20-bit raw temperature (data sheet §8.1)."""
    t1, t2, t3 = trim["T"]
    v1 = (adc_t / 16384.0 - t1 / 1024.0) * t2
    v2 = (adc_t / 131072.0 - t1 / 8192.0) ** 2 * t3
    t_fine = v1 + v2
    return t_fine / 5120.0, t_fine


def compensate_p(adc_p: int, t_fine: float, trim: dict) -> float:
    """Pressure in Pa from the 20-bit raw pressure (data sheet §8.1)."""
    p1, p2, p3, p4, p5, p6, p7, p8, p9 = trim["P"]
    v1 = t_fine / 2.0 - 64000.0
    v2 = v1 * v1 * p6 / 32768.0 + v1 * p5 * 2.0
    v2 = v2 / 4.0 + p4 * 65536.0
    v1 = (p3 * v1 * v1 / 524288.0 + p2 * v1) / 524288.0
    v1 = (1.0 + v1 / 32768.0) * p1
    if v1 == 0.0:
        return 0.0  # (the data sheet's guard against a division by zero)
    p = (1048576.0 - adc_p - v2 / 4096.0) * 6250.0 / v1
    return p + (p9 * p * p / 2147483648.0 + p * p8 / 32768.0 + p7) / 16.0


def compensate_h(adc_h: int, t_fine: float, trim: dict) -> float:
    """Relative humidity in % from the 16-bit raw humidity (data sheet §8.1), clamped to 0..100."""
    h1, h2, h3, h4, h5, h6 = trim["H"]
    x = t_fine - 76800.0
    x = (adc_h - (h4 * 64.0 + h5 / 16384.0 * x)) * (h2 / 65536.0 * (1.0 + h6 / 67108864.0 * x *
                                                                    (1.0 + h3 / 67108864.0 * x)))
    x = x * (1.0 - h1 * x / 524288.0)
    return min(100.0, max(0.0, x))


def compensate(raw: bytes, trim: dict) -> tuple[float, float, float]:
    """(temp_c, pressure_kpa, rh_pct) from the 8 data registers 0xF7..0xFE."""
    adc_p = (raw[0] << 12) | (raw[1] << 4) | (raw[2] >> 4)
    adc_t = (raw[3] << 12) | (raw[4] << 4) | (raw[5] >> 4)
    adc_h = (raw[6] << 8) | raw[7]
    temp_c, t_fine = compensate_t(adc_t, trim)
    return temp_c, compensate_p(adc_p, t_fine, trim) / 1000.0, compensate_h(adc_h, t_fine, trim)


class BME280:
    """One BME280 on an SMBus-like ``bus`` (``i2c_rdwr``); :meth:`read` makes one forced conversion."""

    def __init__(self, bus, address: int = DEFAULT_ADDRESS, *, sleep=time.sleep) -> None:
        from smbus2 import i2c_msg  # the only place smbus2 types appear here

        self._msg = i2c_msg
        self.bus = bus
        self.address = address
        self._sleep = sleep
        self._trim: dict | None = None

    def _read(self, reg: int, n: int) -> bytes:
        wr, rd = self._msg.write(self.address, [reg]), self._msg.read(self.address, n)
        try:
            self.bus.i2c_rdwr(wr, rd)
        except OSError as exc:
            raise AmbientSensorError(f"BME280 at 0x{self.address:02x}: no answer ({exc})") from None
        return bytes(rd)[:n]

    def _write(self, reg: int, value: int) -> None:
        try:
            self.bus.i2c_rdwr(self._msg.write(self.address, [reg, value]))
        except OSError as exc:
            raise AmbientSensorError(f"BME280 at 0x{self.address:02x}: no answer ({exc})") from None

    def chip_id(self) -> int:
        return self._read(REG_ID, 1)[0]

    def trimming(self) -> dict:
        if self._trim is None:
            cid = self.chip_id()
            if cid != CHIP_ID:
                what = "a BMP280 (no humidity)" if cid == 0x58 else "not a BME280"
                raise AmbientSensorError(f"device at 0x{self.address:02x} has chip id 0x{cid:02x}: {what}")
            self._trim = parse_trimming(self._read(REG_CALIB_TP, 24), self._read(REG_CALIB_H1, 1)[0],
                                        self._read(REG_CALIB_H, 7))
        return self._trim

    def read(self) -> tuple[float, float, float]:
        """(temp_c, station pressure_kpa, rh_pct): one forced conversion, waited for (≤ 50 ms)."""
        trim = self.trimming()
        self._write(REG_CTRL_HUM, CTRL_HUM_X1)  # (takes effect with the ctrl_meas write after it)
        self._write(REG_CTRL_MEAS, CTRL_MEAS_FORCED_X1)
        for _ in range(10):
            self._sleep(0.005)
            if not self._read(REG_STATUS, 1)[0] & STATUS_MEASURING:
                break
        else:
            raise AmbientSensorError(f"BME280 at 0x{self.address:02x}: conversion did not finish in 50 ms")
        return compensate(self._read(REG_DATA, 8), trim)


def read_sensor(sensor, what: str, rig_path: str = "rig.toml") -> Ambient:
    """One reading as an :class:`Ambient`; a sensor that fails or reads nonsense: ConfigError naming
    ``[ambient] sensor`` (the run is refused in one line, exit 2)."""
    from dyno.analysis.air import Ambient, check_air
    from dyno.errors import ConfigError

    try:
        t, p, rh = sensor.read()
        check_air(t, p, rh, what)
    except (AmbientSensorError, ValueError) as exc:
        raise ConfigError(rig_path, "[ambient] sensor", f"\"bme280\" is declared but does not answer with a plausible "
                          f"day ({exc}); check its wiring and address, or set sensor = \"none\"") from None
    return Ambient(round(t, 3), round(p, 4), round(rh, 2), "sensor")
