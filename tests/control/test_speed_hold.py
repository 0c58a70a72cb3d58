import pytest
"""The speed-hold law (pure): sign, sigma-delta pulses, dead band, anti-windup."""

from dyno.control.outputs import APPLY, RELEASE, STOP
from dyno.control.hold_law import HoldGains as SpeedHoldGains, HoldLaw as SpeedHold

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def test_too_fast_applies_too_slow_releases():
    h = SpeedHold(SpeedHoldGains(kp=3.0, ki_per_s=0.0, period_s=0.05, min_pulse_s=0.02))
    u = h.update(3300.0, 3000.0, 0.05)  # 10 % too fast: more brake
    assert u > 0
    # 0.015 s of travel a period: the first period owes it, the second gives a 0.03 s pulse
    assert h.pulse(u, 0.1) == (STOP, 0.0)
    direction, on_s = h.pulse(u, 0.1)
    assert direction == APPLY and abs(on_s - 2 * 0.05 * u) < 1e-12
    h = SpeedHold(SpeedHoldGains(kp=3.0, ki_per_s=0.0, period_s=0.05, min_pulse_s=0.02))
    u = h.update(2700.0, 3000.0, 0.05)
    assert u < 0 and [h.pulse(u, -0.1)[0] for _ in range(2)] == [STOP, RELEASE]


def test_small_commands_accumulate_into_minimum_pulses():
    g = SpeedHoldGains(kp=3.0, ki_per_s=0.0, period_s=0.05, min_pulse_s=0.02, deadband_rel=0.001)
    h = SpeedHold(g)
    e = 0.01  # u = 0.03: 1.5 ms of travel a period, far below the 20 ms minimum pulse
    out = [h.pulse(h.update(3000 * (1 + e), 3000.0, 0.05), e) for _ in range(40)]
    pulses = [o for o in out if o[0] != STOP]
    assert pulses and all(on >= g.min_pulse_s for _, on in pulses)
    # the travel given equals the travel asked for, within one minimum pulse
    assert abs(sum(on for _, on in pulses) - 40 * 0.03 * 0.05) <= g.min_pulse_s


def test_dead_band_and_no_speed_mean_no_motion():
    h = SpeedHold(SpeedHoldGains(deadband_rel=0.004))
    assert h.pulse(h.update(3006.0, 3000.0, 0.05), 0.002) == (STOP, 0.0)
    assert h.update(float("nan"), 3000.0, 0.05) == 0.0 and h.update(0.0, 3000.0, 0.05) == 0.0


def test_integral_does_not_wind_up_while_saturated():
    h = SpeedHold(SpeedHoldGains(kp=3.0, ki_per_s=1.0))
    for _ in range(100):  # 50 % too fast for 5 s: the command saturates at +1
        assert h.update(4500.0, 3000.0, 0.05) == 1.0
    assert h.integral == 0.0


def test_owed_travel_survives_the_dead_band_on_the_same_side():
    """At the band's edge kp·e·T is a fraction of a ms a period: if the band dropped the travel already
    owed, the first pulse after the error leaves it would come seconds late (the long step responses
    of docs/control.md "The holds").  Kept, it comes at once; dropped when the error changes side."""
    g = SpeedHoldGains(kp=3.0, ki_per_s=0.0, period_s=0.05, min_pulse_s=0.02, deadband_rel=0.004, lead_s=0.0,
                       fine_pulse_s=0.0)  # one minimum pulse everywhere (the fine one: the next test)
    h = SpeedHold(g)
    e = 0.02  # 2 % too fast: 3 ms of travel a period
    for _ in range(5):  # 15 ms owed, below the minimum pulse
        assert h.pulse(h.command(e, g.period_s), e) == (STOP, 0.0)
    for e in (0.003, 0.001, 0.002):  # back inside the band on the same side: no motion
        assert h.pulse(h.command(e, g.period_s), e) == (STOP, 0.0)
    e = 0.0045  # out again by a hair: 0.7 ms a period on top of the 15 ms kept
    out = [h.pulse(h.command(e, g.period_s), e) for _ in range(8)]
    assert all(o == (STOP, 0.0) for o in out[:7])
    assert out[7][0] == APPLY and out[7][1] >= g.min_pulse_s  # the old hold: 30 periods (1.5 s) to the first
    # An error that changes side inside the band makes the ask stale: nothing is owed any more.
    h = SpeedHold(g)
    for _ in range(6):
        h.pulse(h.command(0.02, g.period_s), 0.02)
    assert h.owed_s > 0
    h.pulse(h.command(-0.001, g.period_s), -0.001)
    assert h.owed_s == 0.0
    e = -0.0045  # too slow now: the first pulse is a release, after the travel of a minimum pulse is owed
    out = [h.pulse(h.command(e, g.period_s), e)[0] for _ in range(40)]
    assert APPLY not in out and out.index(RELEASE) >= 29


def test_after_a_reversal_near_the_setpoint_the_minimum_pulse_is_the_fine_one():
    """Near the setpoint (within ``fine_band_rel``, one lead ahead) a pulse against the last one means the last
    correction crossed the whole dead band: from then on the owed travel becomes a pulse once it is worth
    ``fine_pulse_s``; before any reversal, or farther out, it waits for ``min_pulse_s``.  (With the CVT's sheaves
    stuck in the shift friction's dead band one 20 ms pulse moves the secondary ~1 %: wider than the +-0.5 %
    the hold must keep, and the hold limit-cycled one pulse each way.)"""
    g = SpeedHoldGains(kp=3.0, ki_per_s=0.0, period_s=0.05, min_pulse_s=0.02, deadband_rel=0.004, lead_s=0.0,
                       fine_pulse_s=0.01, fine_band_rel=0.01)

    def first_pulse(h, e):
        for i in range(100):
            d, on_s = h.pulse(h.command(e, g.period_s), e)
            if d != STOP:
                return i, d, on_s

    h = SpeedHold(g)
    i, d, on_s = first_pulse(h, 0.008)  # 1.2 ms a period, no reversal yet: 17 periods owe 20.4 ms
    assert (i, d) == (16, APPLY) and on_s >= g.min_pulse_s and not h.fine
    i, d, on_s = first_pulse(h, -0.008)  # the reversal: 9 periods owe 10.8 ms
    assert (i, d) == (8, RELEASE) and g.fine_pulse_s <= on_s < g.min_pulse_s and h.fine
    i, d, on_s = first_pulse(h, 0.008)  # fine from here on, either way
    assert (i, d) == (8, APPLY) and on_s < g.min_pulse_s
    i, d, on_s = first_pulse(h, 0.012)  # outside the fine band: 1.8 ms a period, 12 periods to 20 ms
    assert (i, d) == (11, APPLY) and on_s >= g.min_pulse_s and not h.fine
    h.reset()
    assert not h.fine and h.last_dir == 0


def test_the_lead_sets_the_brake_position_by_the_error_and_waits_for_a_correction_under_way():
    """u = kp·(e + lead·de/dt): integrated by the actuator, the lead part moves the brake by kp·lead·Δe (a
    position in proportion to the error); and the dead band is judged on e + lead·de/dt, so an error outside the
    band that is already closing fast enough (a correction the plant's lag still hides) asks for no pulse."""
    g = SpeedHoldGains(kp=12.0, lead_s=0.5, period_s=0.05, min_pulse_s=0.02, deadband_rel=0.004,
                       derivative_window_s=0.1, fine_pulse_s=0.0)
    h = SpeedHold(g)
    for _ in range(3):
        h.command(0.0, g.period_s)
    # a step of the error from 0 to 1 %: the rate over the 0.1 s window is 0.01/0.1 s -> kp·lead·rate = 0.6
    u = h.command(0.01, g.period_s)
    assert u == pytest.approx(12.0 * 0.01 + 12.0 * 0.5 * 0.01 / 0.1)
    # 0.6 % too fast for three periods: travel owed (3.6 ms a period), not yet a minimum pulse
    def primed():
        h = SpeedHold(g)
        for _ in range(3):
            assert h.pulse(h.command(0.006, g.period_s), 0.006) == (STOP, 0.0)
        return h
    h = primed()
    owed = h.owed_s
    assert owed == pytest.approx(3 * 12.0 * 0.006 * 0.05)
    # then 0.5 %, closing at 1 %/s: one lead ahead it is at 0, inside the band -> no pulse, nothing added
    for e in (0.0055, 0.0050):
        assert h.pulse(h.command(e, g.period_s), e) == (STOP, 0.0)
    assert h.e_lead == pytest.approx(0.0050 - 0.5 * 0.01) and h.owed_s == pytest.approx(owed)
    # the same 0.5 % then held still: once the rate window has forgotten the step (0.1 s), the error is outside
    # the band where it is heading too -> the owed travel becomes a pulse
    h = primed()
    out = [h.pulse(h.command(0.0050, g.period_s), 0.0050) for _ in range(7)]
    assert out[:2] == [(STOP, 0.0)] * 2 and any(d == APPLY and on >= g.min_pulse_s for d, on in out[2:]), out
