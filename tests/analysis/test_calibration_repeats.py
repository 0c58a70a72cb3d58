"""The slope's reproducibility over repeated calibrations (dyno calibrate --repeats): the maths."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dyno.analysis.calibration import REPRODUCIBILITY_TARGET_REL, fit_calibration, fit_repeats, slope_reproducibility
from dyno.analysis.calibration_history import CalibrationRejected

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

LOADS_NM = [3.9, 7.8, 11.8, 15.7, 19.6, 15.7, 11.8, 7.8, 3.9]
DIRECTION = [1, 1, 1, 1, 1, -1, -1, -1, -1]


def test_reproducibility_is_the_relative_sd_of_the_slopes_and_its_mean_s_error():
    r = slope_reproducibility([99.0, 100.0, 101.0])
    assert r.n == 3 and r.mean_slope == 100.0
    assert r.rel_sd == pytest.approx(0.01)  # sd 1 (n - 1 dof) over the mean 100
    assert r.rel_se == pytest.approx(0.01 / math.sqrt(3))
    assert not r.meets() and slope_reproducibility([100.0, 100.3, 99.8]).meets()
    assert REPRODUCIBILITY_TARGET_REL == 0.004  # the figure docs/analysis.md measured for U95 <= 2 pp
    one = slope_reproducibility([600.0])
    assert math.isnan(one.rel_sd) and math.isnan(one.rel_se) and not one.meets()  # one cannot show its own spread
    for bad in ([], [100.0, -1.0], [100.0, math.nan]):
        with pytest.raises(ValueError):
            slope_reproducibility(bad)


def test_reproducibility_estimates_the_true_spread_without_bias():
    """Its square is the unbiased variance estimate: over many sets of 4 repeats drawn with a 0.4 % slope
    spread, the mean of rel_sd^2 is 0.4 %^2 (within its own sampling error)."""
    rng = np.random.default_rng(27)
    true_rel = 0.004
    sets = 600.0 * (1.0 + true_rel * rng.standard_normal((4000, 4)))
    var = np.array([slope_reproducibility(s).rel_sd ** 2 for s in sets])
    assert var.mean() == pytest.approx(true_rel ** 2, rel=0.05)


def _counts(slope, intercept, rng=None, noise=0.0):
    rng = rng or np.random.default_rng(0)
    return [slope * t + intercept + noise * rng.standard_normal(50) for t in LOADS_NM]


def test_fit_repeats_fits_each_repeat_and_the_whole():
    """Three exact repeats at slopes 600, 602.4, 597.6: each repeat's fit returns its slope, the spread is
    0.4 %, and the whole line is the fit through every step."""
    slopes = [600.0, 602.4, 597.6]
    torques, counts, repeat, direction = [], [], [], []
    for k, a in enumerate(slopes):
        torques += LOADS_NM
        counts += _counts(a, 33500.0)
        repeat += [k] * len(LOADS_NM)
        direction += DIRECTION
    whole, rep = fit_repeats(torques, counts, repeat, direction=direction, r2_min=0.99)
    assert rep.slopes == pytest.approx(slopes, abs=1e-9)
    assert rep.rel_sd == pytest.approx(0.004, rel=1e-9)
    ref = fit_calibration(torques, counts, direction=direction, r2_min=0.99)
    assert whole.slope_counts_per_nm == pytest.approx(ref.slope_counts_per_nm)
    assert whole.slope_counts_per_nm == pytest.approx(600.0, abs=0.01)  # the repeats' loads are the same


def test_fit_repeats_with_one_repeat_is_the_plain_fit():
    whole, rep = fit_repeats(LOADS_NM, _counts(590.0, 33400.0, noise=60.0), [0] * len(LOADS_NM),
                             direction=DIRECTION)
    assert rep.n == 1 and rep.slopes == (whole.slope_counts_per_nm,) and math.isnan(rep.rel_sd)


def test_a_bad_repeat_is_refused_by_name():
    torques, counts, repeat = [], [], []
    for k in range(3):
        torques += LOADS_NM
        c = _counts(600.0, 33500.0)
        if k == 1:  # the second pass: a rope slipping at the top load
            c[4] = c[4] - 3000.0
        counts += c
        repeat += [k] * len(LOADS_NM)
    with pytest.raises(CalibrationRejected, match="R\\^2"):
        fit_repeats(torques, counts, repeat)
    with pytest.raises(CalibrationRejected, match="repeat 2 of 3"):
        fit_repeats(torques, counts, repeat, r2_min=0.95)  # the whole passes (0.967); the second repeat alone does not
    with pytest.raises(ValueError):
        fit_repeats(torques, counts, repeat[:-1])


def test_the_friction_term_takes_a_cradles_bearings_out_of_the_slope():
    """A load cell with Coulomb friction b in its load path reads T - b loading, T + b unloading; the up/down
    sequence visits its top load only loading, so the plain line tilts (about -0.036 b per N·m here); the
    friction term fits the line between the branches and returns b."""
    a, c0, b = 600.0, 33500.0, 0.07
    means = [a * (t - sgn * b) + c0 for t, sgn in zip(LOADS_NM, DIRECTION)]
    plain = fit_calibration(LOADS_NM, means, direction=DIRECTION)
    assert plain.slope_counts_per_nm / a - 1.0 == pytest.approx(-0.036 * b, rel=0.05)  # -0.25 %
    assert plain.friction_counts is None and plain.friction_nm is None
    f = fit_calibration(LOADS_NM, means, direction=DIRECTION, friction_term=True)
    assert f.slope_counts_per_nm == pytest.approx(a) and f.intercept_counts == pytest.approx(c0)
    assert f.friction_nm == pytest.approx(b) and f.friction_se_counts == pytest.approx(0.0, abs=1e-6)
    # without both directions there is no branch to separate: the plain line
    up = [i for i, d in enumerate(DIRECTION) if d > 0]
    g = fit_calibration([LOADS_NM[i] for i in up], [means[i] for i in up], direction=[1] * len(up),
                        friction_term=True)
    assert g.friction_counts is None and g.slope_counts_per_nm == pytest.approx(a)
