"""A window that cannot become a point gives up during its minimum length, not after it
(dyno.control.measuring.Measuring._wait_minimum)."""

import asyncio
from types import SimpleNamespace

import pytest

from dyno.control.measuring import Measuring

pytestmark = pytest.mark.quick


class _Clocked(Measuring):
    def __init__(self, check_s: float) -> None:
        self.t = 0.0
        self.plan = SimpleNamespace(measure_check_s=check_s)
        self.sleeps: list[float] = []

    def rig_now(self) -> float:
        return self.t

    async def rig_sleep(self, dt_s: float) -> None:
        self.sleeps.append(dt_s)
        self.t += dt_s


def test_a_drift_seen_mid_window_ends_the_minimum_at_the_next_look():
    m = _Clocked(0.25)
    lost = asyncio.run(m._wait_minimum(2.0, give_up=lambda: m.t >= 0.6))
    assert lost and m.t == pytest.approx(0.75)  # the look after the drift, not the minimum's 2 s


def test_a_steady_window_waits_its_whole_minimum_and_one_without_a_give_up_sleeps_once():
    m = _Clocked(0.25)
    assert not asyncio.run(m._wait_minimum(2.0, give_up=lambda: False))
    assert m.t == pytest.approx(2.0) and len(m.sleeps) == 8
    m = _Clocked(0.25)
    assert not asyncio.run(m._wait_minimum(2.0))
    assert m.sleeps == [pytest.approx(2.0)]
