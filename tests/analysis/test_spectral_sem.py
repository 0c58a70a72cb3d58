"""The standard error of a window's mean from the low end of its spectrum (dyno.analysis.spectral_sem): honest
on white noise with the torque channel's ripple lines on top, and with many more degrees of freedom than
0.5 s batches."""

import math

import numpy as np
import pytest
from scipy import stats

from dyno.analysis.points import batch_count
from dyno.analysis.spectral_sem import spectral_sem

pytestmark = pytest.mark.quick

FS_HZ = 127.0


def _window(rng, duration_s, sigma=160.0):
    t = np.arange(int(duration_s * FS_HZ)) / FS_HZ
    ripple = (800.0 * np.sin(2 * np.pi * 26.0 * t + rng.uniform(0, 6.3))  # firing order, post-filter
              + 200.0 * np.sin(2 * np.pi * 11.0 * t + rng.uniform(0, 6.3)))  # brake-shaft order, heavy load
    return t, sigma * rng.standard_normal(t.size) + ripple


@pytest.mark.parametrize("duration_s", [2.5, 4.0])
def test_the_95_percent_interval_covers_the_mean_at_its_nominal_rate(duration_s):
    rng = np.random.default_rng(7)
    inside, n, dofs = 0, 600, set()
    for _ in range(n):
        _, x = _window(rng, duration_s)
        sem, dof = spectral_sem(x, duration_s)
        dofs.add(dof)
        inside += abs(x.mean()) <= stats.t.ppf(0.975, dof) * sem  # the true mean is 0 (lines average out)
    assert dofs == {2 * int(4.0 * duration_s)}
    assert 0.92 <= inside / n <= 0.98


def test_more_degrees_of_freedom_than_batches_and_none_from_too_short_a_window():
    rng = np.random.default_rng(3)
    _, x = _window(rng, 3.0)
    sem, dof = spectral_sem(x, 3.0)
    assert dof == 24 > batch_count(0, 3_000_000) - 1 == 5
    assert sem == pytest.approx(160.0 / math.sqrt(x.size), rel=0.35)
    assert spectral_sem(x[:100], 0.8) == (pytest.approx(math.nan, nan_ok=True), 0)  # 3 bins: too few
