"""The BME280 driver against the simulated chip: the data sheet's compensation inverted by the chip and
applied by the host round-trips the day; a wrong chip or a silent bus is one clear error."""

from __future__ import annotations

import errno

import pytest

from dyno.hw.bme280 import BME280, AmbientSensorError, compensate, pack_trimming, parse_trimming
from dyno.sim.bme280_chip import TRIMMING, SimBME280, raw_words
from dyno.sim.world import World

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


class _Bus:
    def __init__(self, dev):
        self.dev = dev

    def i2c_rdwr(self, *msgs):
        self.dev.transaction(msgs)


def test_trimming_registers_round_trip():
    assert parse_trimming(*pack_trimming(TRIMMING)) == TRIMMING


@pytest.mark.parametrize("t, p, rh", [(-10.0, 80.0, 0.0), (25.0, 99.0, 40.0), (45.0, 105.0, 100.0),
                                      (3.3, 87.65, 12.5)])
def test_compensation_round_trip(t, p, rh):
    got = compensate(raw_words(t, p, rh), TRIMMING)
    assert got[0] == pytest.approx(t, abs=0.01)
    assert got[1] == pytest.approx(p, abs=0.003)  # 3 Pa: the 20-bit word's step
    assert got[2] == pytest.approx(rh, abs=0.05)


def test_driver_reads_the_day_through_the_chip_errors():
    w = World(31.0, 91.5, 35.0, 1.1)
    chip = SimBME280(w, seed=4)
    t, p, rh = BME280(_Bus(chip), sleep=lambda s: None).read()
    assert (t, p, rh) == pytest.approx(chip.reading(), abs=0.01)
    assert abs(t - 31.0) < 2.0 and abs(p - 91.5) < 0.2 and abs(rh - 35.0) < 6.0  # within the data sheet
    assert chip.conversions == 1


def test_wrong_chip_and_silent_bus_are_errors():
    chip = SimBME280(World(25.0, 99.0, 0.0, 1.0))
    chip.regs[0xD0] = 0x58
    with pytest.raises(AmbientSensorError, match="BMP280"):
        BME280(_Bus(chip), sleep=lambda s: None).read()

    class _Dead:
        def i2c_rdwr(self, *msgs):
            raise OSError(errno.EREMOTEIO, "NACK")

    with pytest.raises(AmbientSensorError, match="no answer"):
        BME280(_Dead(), sleep=lambda s: None).read()
