"""The simulated BME280: its registers, as the host's driver (:mod:`dyno.hw.bme280`) reads them.

It reports the simulated day (:attr:`dyno.sim.physics.RigModel.world`) through the chip's own
errors — a per-seed offset within the data sheet's absolute accuracy (±1 °C, ±1 hPa, ±3 %RH, taken
as a normal with those as 2 sigma) — by inverting the data sheet's compensation: the raw words are
found (bisection on the monotone formulas) that the host's :func:`~dyno.hw.bme280.compensate` turns
back into those values.  Served on the simulated bus only when ``rig.toml [ambient] sensor = "bme280"``.
"""

from __future__ import annotations

import ctypes
import errno

import numpy as np

from dyno.hw.bme280 import (CHIP_ID, REG_CALIB_H, REG_CALIB_H1, REG_CALIB_TP, REG_DATA, REG_ID, compensate_h,
                            compensate_p, compensate_t, pack_trimming)

I2C_M_RD = 0x0001
#: The data sheet's example trimming (T, P: §8.2) and a real chip's humidity words.
TRIMMING = {"T": (27504, 26435, -1000), "P": (36477, -10685, 3024, 2855, 140, -7, 15500, -14600, 6000),
            "H": (75, 362, 0, 313, 50, 30)}


def _bisect(f, target: float, lo: int, hi: int, increasing: bool) -> int:
    """The integer raw word in [lo, hi] whose compensated value is nearest ``target``."""
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if (f(mid) < target) == increasing:
            lo = mid
        else:
            hi = mid
    return lo if abs(f(lo) - target) <= abs(f(hi) - target) else hi


def raw_words(temp_c: float, pressure_kpa: float, rh_pct: float, trim=TRIMMING) -> bytes:
    """The 8 data registers (0xF7..0xFE) that compensate to these values."""
    adc_t = _bisect(lambda a: compensate_t(a, trim)[0], temp_c, 0, (1 << 20) - 1, True)
    t_fine = compensate_t(adc_t, trim)[1]
    adc_p = _bisect(lambda a: compensate_p(a, t_fine, trim), pressure_kpa * 1000.0, 0, (1 << 20) - 1, False)
    adc_h = _bisect(lambda a: compensate_h(a, t_fine, trim), rh_pct, 0, (1 << 16) - 1, True)
    return bytes([adc_p >> 12, (adc_p >> 4) & 0xFF, (adc_p & 0x0F) << 4,
                  adc_t >> 12, (adc_t >> 4) & 0xFF, (adc_t & 0x0F) << 4, adc_h >> 8, adc_h & 0xFF])


class SimBME280:
    """Register file of one BME280 answering ``i2c_rdwr`` messages (write pointer, then read)."""

    def __init__(self, world, seed: int = 0, temp_bias_c: float = 0.0) -> None:
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x280]))
        # the chip's own error this seed (2 sigma = the data sheet's absolute accuracy), and where it sits
        # (``temp_bias_c``: RigParams.bme280_temp_bias_c, a sensor reading warm)
        self.error = (0.5 * float(rng.normal()) + float(temp_bias_c), 0.05 * float(rng.normal()),
                      1.5 * float(rng.normal()))
        self.world = world
        tp, h1, h = pack_trimming(TRIMMING)
        self.regs = bytearray(256)
        self.regs[REG_CALIB_TP:REG_CALIB_TP + 24] = tp
        self.regs[REG_CALIB_H1] = h1
        self.regs[REG_CALIB_H:REG_CALIB_H + 7] = h
        self.regs[REG_ID] = CHIP_ID
        self.conversions = 0
        self.lost = False  # the sensor unplugged (tests)

    def reading(self) -> tuple[float, float, float]:
        """What the chip measures now: the day plus its own error."""
        w = self.world
        return (w.temp_c + self.error[0], w.pressure_kpa + self.error[1],
                min(100.0, max(0.0, w.rh_pct + self.error[2])))

    def transaction(self, msgs) -> None:
        if self.lost:
            raise OSError(errno.EREMOTEIO, "BME280: NACK")
        ptr = 0
        for msg in msgs:
            if msg.flags & I2C_M_RD:
                data = bytes(self.regs[ptr:ptr + msg.len]).ljust(msg.len, b"\x00")
                ctypes.memmove(msg.buf, data, msg.len)
            else:
                data = bytes(msg)
                if not data:
                    continue
                ptr = data[0]
                for i, v in enumerate(data[1:]):
                    self._write(ptr + i, v)

    def _write(self, reg: int, value: int) -> None:
        self.regs[reg] = value
        if reg == 0xF4 and value & 0x03 in (0x01, 0x02):  # forced mode: convert now (done by the next read)
            self.regs[REG_DATA:REG_DATA + 8] = raw_words(*self.reading())
            self.regs[0xF4] = value & ~0x03  # back to sleep mode, as the chip does after a forced conversion
            self.conversions += 1
