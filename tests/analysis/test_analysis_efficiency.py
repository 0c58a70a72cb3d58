"""Batch-means SEM and point efficiency with first-order uncertainty."""

import math

import numpy as np
import pytest

from dyno.analysis.efficiency import batch_mean, point_efficiency
from dyno.analysis.engine_map import EngineMap
from dyno.analysis.engine_map_range import NoMapPower, OutOfMapRange

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

RPM = np.array([1500, 2000, 2500, 3000, 3400, 3600, 3850.0])
TORQUE = np.array([15.0, 17.5, 18.6, 18.0, 16.3, 13.0, 0.0])
MAP = EngineMap(RPM, TORQUE, source="test-map", sha256="cafe")


def test_analysis_batch_mean_basic():
    x = np.repeat([1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 10)
    mean, sem = batch_mean(x)
    assert mean == pytest.approx(3.5)
    assert sem == pytest.approx(np.std([1, 2, 3, 4, 5, 6], ddof=1) / math.sqrt(6))
    with pytest.raises(ValueError):
        batch_mean([1.0, 2.0], n_batches=6)
    with pytest.raises(ValueError):
        batch_mean([1.0, math.nan] * 10)


def test_analysis_batch_mean_sem_honest_for_correlated_ripple():
    # 3 s at 125 Hz of AR(1) noise (correlation time ~ 20 samples) + firing ripple:
    # the batch SEM must track the true scatter of the mean, the naive one must not.
    rng = np.random.default_rng(7)
    n, phi = 375, 0.95
    t = np.arange(n) / 125.0
    means, sems, naive = [], [], []
    for _ in range(400):
        e = rng.normal(0, 1, n)
        x = np.empty(n)
        x[0] = e[0] / math.sqrt(1 - phi ** 2)
        for i in range(1, n):
            x[i] = phi * x[i - 1] + e[i]
        x += 3 * np.sin(2 * np.pi * 25 * t + rng.uniform(0, 2 * np.pi))
        m, s = batch_mean(x)
        means.append(m)
        sems.append(s)
        naive.append(x.std(ddof=1) / math.sqrt(n))
    true_sem = np.std(means)
    assert np.sqrt(np.mean(np.square(sems))) == pytest.approx(true_sem, rel=0.3)
    assert np.mean(naive) < 0.5 * true_sem


def test_analysis_point_efficiency_values():
    r = point_efficiency(3000, 5, 2500, 5, 20.0, 0.1, MAP)
    p_in = 18.0 * 3000 * 2 * math.pi / 60
    p_out = 20.0 * 2500 * 2 * math.pi / 60
    assert r["power_in_w"] == pytest.approx(p_in)
    assert r["power_out_w"] == pytest.approx(p_out)
    assert r["efficiency"] == pytest.approx(p_out / p_in)
    assert r["engine_map_sha256"] == "cafe"
    zero = point_efficiency(3000, 0, 2500, 0, 20.0, 0, MAP)
    assert zero["efficiency_sem"] == 0.0


def test_analysis_point_efficiency_sem_matches_monte_carlo():
    rng = np.random.default_rng(11)
    args = dict(rpm_primary=3500.0, rpm_primary_sem=15.0, rpm_secondary=2200.0,
                rpm_secondary_sem=12.0, torque_secondary_nm=19.0, torque_secondary_sem=0.25)
    r = point_efficiency(**args, engine_map=MAP)
    n = 200_000
    rp = rng.normal(args["rpm_primary"], args["rpm_primary_sem"], n)
    rs = rng.normal(args["rpm_secondary"], args["rpm_secondary_sem"], n)
    tq = rng.normal(args["torque_secondary_nm"], args["torque_secondary_sem"], n)
    eta = tq * rs * 2 * np.pi / 60 / MAP.power_w(rp)
    assert r["efficiency"] == pytest.approx(np.mean(eta), rel=2e-3)
    assert r["efficiency_sem"] == pytest.approx(np.std(eta), rel=0.03)
    # the map slope term matters here (droop side of the curve): without it the SEM is smaller
    r0 = point_efficiency(**{**args, "rpm_primary_sem": 0.0}, engine_map=MAP)
    assert r0["efficiency_sem"] < 0.9 * r["efficiency_sem"]


def test_analysis_point_efficiency_refuses_engine_speed_outside_map():
    with pytest.raises(OutOfMapRange, match="3900"):
        point_efficiency(3900, 5, 2500, 5, 20.0, 0.1, MAP)
    with pytest.raises(NoMapPower, match="0 W at 3850"):
        point_efficiency(3850, 5, 2500, 5, 20.0, 0.1, MAP)  # still an OutOfMapRange
    with pytest.raises(ValueError, match="torque_secondary_sem"):
        point_efficiency(3000, 5, 2500, 5, 20.0, -0.1, MAP)
