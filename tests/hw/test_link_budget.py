"""The link budget (issue 53): derating a poll rate that does not fit instead of refusing it, a bus clock above
a device's rating refused naming the device, and the real transports measured from their transfers' own
durations."""

from __future__ import annotations

import dataclasses

import pytest

from dyno.errors import ConfigError
from dyno.hw.clock import FakeClock
from dyno.rig.config import load_rig
from dyno.transports.budget import (MAX_BUSY, LinkMeter, TimedTransport, check_budget, max_poll_hz, metered_rig_link,
                                    planned_busy)

pytestmark = pytest.mark.quick


def _rig(**i2c):
    rig = load_rig()
    return dataclasses.replace(rig, i2c=dataclasses.replace(rig.i2c, **i2c)) if i2c else rig


def test_a_poll_rate_that_does_not_fit_is_derated_to_fit_and_said():
    slow = _rig(bus_speed_hz=50_000)  # the old default clock: 150 polls would keep the bus ~110 % busy
    said = []
    ran = check_budget(slow, say=said.append)
    assert ran.poll_hz == max_poll_hz(slow) == 81 and ran.derated_from_hz == 150
    assert planned_busy(ran) <= MAX_BUSY < planned_busy(slow)
    assert len(said) == 1 and "derated from 150 Hz to 81 Hz" in said[0] and "poll_hz" in said[0]
    assert check_budget(load_rig()) == load_rig()  # a rig that fits runs as its file says


def test_derate_false_refuses_in_one_line_naming_poll_hz():
    slow = dataclasses.replace(_rig(bus_speed_hz=50_000), derate=False)
    with pytest.raises(ConfigError, match=r"poll_hz: at most 81 Hz .*set derate = true"):
        check_budget(slow)


def test_a_clock_above_a_devices_rating_is_refused_naming_it():
    with pytest.raises(ConfigError, match=r"i2c.bus_speed_hz: at most 100000 Hz: the MLX90614 .* 0x5A"):
        check_budget(_rig(bus_speed_hz=400_000))  # 400 kHz fits the polls, not the thermometer
    serial = dataclasses.replace(load_rig(), transport="serial")
    with pytest.raises(ConfigError, match="MLX90614"):  # the thermometer is on the Pi's bus on a serial rig too
        check_budget(dataclasses.replace(serial, i2c=dataclasses.replace(serial.i2c, bus_speed_hz=400_000)))


class _SlowTransport:
    """A transport whose transfers take ``busy_s`` of the (fake) clock, as a stretched bus would."""

    def __init__(self, clock, busy_s):
        self.clock, self.busy_s, self.resets = clock, busy_s, 0

    def transfer(self, request, read_len):
        self.clock.advance(self.busy_s)
        return bytes(read_len)

    def write(self, request):
        self.transfer(request, 0)


def test_the_real_link_is_measured_from_each_transfers_own_duration():
    clock = FakeClock(start_s=0.0)
    meter = LinkMeter(clock.now)
    link = TimedTransport(_SlowTransport(clock, 0.004), meter, clock.now)
    for _ in range(3):  # three seconds of 150 polls, each 4 ms on the wire and 2.67 ms idle after
        for _ in range(150):
            link.transfer(b"x", 32)
            clock.advance(1 / 150 - 0.004)
    assert meter.worst_frac() == pytest.approx(0.6, abs=0.01)  # what the transfers took, not what was planned
    assert link.resets == 0  # (the transport's own attributes pass through)


def test_the_rigs_thermometer_reads_are_charged_where_they_share_the_bus():
    clock = FakeClock(start_s=0.0)

    class _Hw:
        transport = _SlowTransport(clock, 0.003)

        class thermometer:
            @staticmethod
            def object_c():
                clock.advance(0.001)
                return 40.0

    transport, read_c, meter = metered_rig_link(_Hw, load_rig(), clock=clock.now)
    transport.transfer(b"x", 32)
    assert read_c() == 40.0
    assert meter.total_s == pytest.approx(0.004) and meter.transactions == 2
