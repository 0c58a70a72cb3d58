"""The kill-path probe's judge (dyno.control.kill_probe.judge_dip) on synthetic one-per-revolution Hall edges:
a cut's deceleration is a dip, a steady or a climbing engine is none, and a rough idle raises the bar."""

import pytest

from dyno.control import kill_probe as kp

pytestmark = pytest.mark.quick


def _edges(rpm_of_t, t0_s=0.3, t1_s=1.3):
    """Edge times (us) of a shaft whose speed follows rpm_of_t(t_s): one edge per revolution."""
    out, t, angle, dt = [], t0_s, 0.0, 2e-5
    while t < t1_s:
        angle += rpm_of_t(t) / 60.0 * dt
        t += dt
        if angle >= 1.0:
            angle -= 1.0
            out.append(int(t * 1e6))
    return out


def _cut(t_cut_s, drop_rpm_per_s=380.0, idle=1800.0):
    """Idle, then a 100 ms cut decelerating at ``drop_rpm_per_s``, then a recovery at the same rate."""
    def rpm(t):
        if t < t_cut_s:
            return idle
        if t < t_cut_s + kp.CUT_S:
            return idle - drop_rpm_per_s * (t - t_cut_s)
        return min(idle, idle - drop_rpm_per_s * kp.CUT_S + drop_rpm_per_s * (t - t_cut_s - kp.CUT_S))
    return rpm


def test_a_cut_is_a_dip_and_no_cut_is_none():
    t_cut_us = 1_000_000
    cut = kp.judge_dip(_edges(_cut(1.0)), t_cut_us)
    assert cut["cut"] and cut["baseline_rpm"] == pytest.approx(1800, abs=1)
    assert 0.6 * 38 <= cut["dip_rpm"] <= 38 + 1, cut  # 38 rpm true fall; two-revolution means see most of it
    steady = kp.judge_dip(_edges(lambda t: 1800.0), t_cut_us)
    assert not steady["cut"] and abs(steady["dip_rpm"]) < 1
    climbing = kp.judge_dip(_edges(lambda t: 1700.0 + 100.0 * t), t_cut_us)  # still recovering: no dip
    assert not climbing["cut"] and climbing["dip_rpm"] <= 0


def test_a_rough_idle_raises_the_dip_needed():
    t_cut_us = 1_000_000
    cut = kp.judge_dip(_edges(_cut(1.0)), t_cut_us, spread_rpm=20.0)
    assert cut["needed_rpm"] == pytest.approx(kp.SPREAD_FACTOR * 20.0) and not cut["cut"]
    assert kp.judge_dip(_edges(_cut(1.0)), t_cut_us, spread_rpm=2.0)["cut"]


def test_too_few_edges_is_not_a_cut():
    out = kp.judge_dip([100_000, 200_000], 1_000_000)
    assert not out["cut"] and "too few" in out["why"]
