"""The hold's settle criterion on the measured speed's rate (dyno.control.readings.Readings.rate_rel_per_s and the
hold service's steadiness, dyno.control.holds)."""

from types import SimpleNamespace

import numpy as np
import pytest

from dyno.control.api import SpeedHold
from dyno.control.holds import HoldService
from dyno.control.readings import Readings

pytestmark = pytest.mark.quick


def _ctx(rpm0: float, rate_rpm_per_s: float, now_s: float = 3.0):
    """A secondary Hall edge per revolution for a speed rpm0 + rate * t, read at ``now_s``."""
    t, edges = 0.0, []
    while t < now_s:
        edges.append(int(t * 1e6))
        t += 60.0 / (rpm0 + rate_rpm_per_s * t)
    e = np.array(edges, dtype=np.int64)
    streams = SimpleNamespace(edge_window=lambda ch, t0, t1: e[(e >= t0) & (e <= t1)])
    poller = SimpleNamespace(device_now_us=lambda: int(now_s * 1e6), streams=streams)
    return Readings(poller, lambda: None)


def speed_rate_rel_per_s(read, sp, window_s):
    return read.rate_rel_per_s(sp, window_s)


def steady(read, sp, rate_rel_per_s=0.0):
    service = HoldService(SimpleNamespace(read=read))
    return service._steady(SpeedHold(sp, settle_rate_rel_per_s=rate_rel_per_s, settle_rate_window_s=0.3))


def test_the_rate_is_the_speeds_own_and_steady_means_under_the_plans_bound():
    moving = _ctx(3000.0, 90.0)  # 3 %/s of 3,000 rpm
    assert speed_rate_rel_per_s(moving, 3000.0, 0.3) == pytest.approx(0.03, rel=0.15)
    assert not steady(moving, 3000.0, 0.01)
    held = _ctx(3000.0, 6.0)  # 0.2 %/s: the brake's slow fade
    assert abs(speed_rate_rel_per_s(held, 3000.0, 0.3)) < 0.01 and steady(held, 3000.0, 0.01)
    assert steady(moving, 3000.0)  # off (0): the dwell alone decides
