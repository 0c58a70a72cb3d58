"""v0's 16-bit sum lets some corrupted frames through: the reader's plausibility check."""

from __future__ import annotations

import pytest

from dyno.acquisition.reader import V0Reader, implausible_v0
from dyno.protocol import v0

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

# a steady state: primary 3,750 rpm (16 ms period), secondary 7,500 rpm (8 ms), ADC every 8 ms
BASE = v0.LegacyFrame(3750, 1_000_000, 7500, 1_004_000, 35000, 1_006_000)


def _next(f: v0.LegacyFrame, dt_us: int = 8000, **kw) -> v0.LegacyFrame:
    """The next poll's frame: a new secondary edge and conversion; the primary slot unchanged."""
    d = dict(rpm_primary=f.rpm_primary, t_primary_us=f.t_primary_us, rpm_secondary=f.rpm_secondary,
             t_secondary_us=f.t_secondary_us + dt_us, adc_code=f.adc_code + 37, t_adc_us=f.t_adc_us + dt_us)
    d.update(kw)
    return v0.LegacyFrame(**d)


def test_physical_frames_pass():
    assert implausible_v0(_next(BASE), BASE, 0.008) is None
    assert implausible_v0(_next(BASE, t_primary_us=BASE.t_primary_us + 16_000), BASE, 0.008) is None
    # two secondary periods since the last edge the host saw (one missed between polls)
    assert implausible_v0(_next(BASE, dt_us=16_000), BASE, 0.016) is None


def test_corrupted_frames_are_refused():
    # the case: a secondary reading of 1 rpm would end the test early
    assert implausible_v0(_next(BASE, rpm_secondary=1), BASE, 0.0067) == "implausible_rpm"
    # a flipped time bit shortens the period: a false over-speed
    assert implausible_v0(_next(BASE, t_primary_us=BASE.t_primary_us + 16_000 - 4096), BASE, 0.0067) \
        == "implausible_period"
    # a value changed without its timestamp
    assert implausible_v0(_next(BASE, rpm_primary=3751), BASE, 0.0067) \
        == "implausible_value"
    # a high time bit: the ADC clock leapt forward
    assert implausible_v0(_next(BASE, t_adc_us=BASE.t_adc_us + (1 << 24)), BASE, 0.0067) == "implausible_time"
    # a high bit of the torque code
    assert implausible_v0(_next(BASE, adc_code=BASE.adc_code ^ (1 << 14)), BASE, 0.0067) == "implausible_adc"


class _Replay:
    """A transport that serves prepared frames."""

    def __init__(self, frames):
        self.frames = list(frames)

    def transfer(self, request, n):
        return v0.encode_legacy_frame(self.frames.pop(0))


def test_an_odd_frame_is_dropped_but_a_real_change_is_kept():
    a = BASE
    b = _next(a)
    odd = _next(b, rpm_secondary=1)  # corrupted (passes the sum by construction here)
    c = _next(_next(b))
    # a real, sudden load change (periods consistent with the new speed) ...
    jump = _next(c, rpm_secondary=5000, t_secondary_us=c.t_secondary_us + 12_000, t_adc_us=c.t_adc_us + 16_000)
    d = _next(jump, rpm_secondary=4900, t_secondary_us=jump.t_secondary_us + 12_245)  # ... confirmed
    r = V0Reader(_Replay([a, b, odd, c, jump, d]))
    got, rejected = [], []
    for i in range(6):
        got.append(r.poll(0.008 * (i + 1)))
        rejected.append(r.stats.rejected["implausible_rpm"])
    assert got[2] == [] and rejected[2] == 0  # the odd frame is held, not yet judged
    assert rejected[3] == 1 and got[3]  # c disagrees with it: dropped as corruption; c accepted
    assert got[4] == []  # the jump is held ...
    secondary = [e.code for e in got[5] if e.channel == 2]
    assert secondary == [5000, 4900]  # ... and accepted with its neighbour
    assert r.stats.rejected["implausible_rpm"] == 1
