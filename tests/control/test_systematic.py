"""The systematic part of a point's uncertainty: calibration reproducibility and engine-map terms."""

import math

import pytest

from dyno.analysis.calibration_history import CalibrationEntry
from dyno.analysis.systematic import calibration_rel_u, interval95, interval_basis, point_systematic

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def _cal(slope, n=0, r2=0.9999):
    return CalibrationEntry(date="2026-01-01", slope_counts_per_nm=slope, intercept_counts=35000.0, r2=r2,
                            n_samples=n)


def test_calibration_term_is_the_slopes_spread_with_the_fit_error():
    hist = [_cal(100.0), _cal(102.0), _cal(98.0)]
    assert calibration_rel_u(hist, hist[-1]) == pytest.approx(0.02)  # sd 2 of mean 100
    fitted = _cal(98.0, n=12, r2=0.999)
    u = calibration_rel_u(hist[:2] + [fitted], fitted)
    fit = math.sqrt(0.001 / (10 * 0.999))
    assert u == pytest.approx(math.hypot(0.02, fit), rel=1e-9)
    assert calibration_rel_u([_cal(100.0)], _cal(100.0)) == 0.0  # one calibration: no spread to state


def test_point_terms_are_95_percent_half_widths_in_quadrature():
    s = point_systematic({"efficiency": 0.85}, 0.015, 0.05)
    assert s["efficiency_sys95_calibration"] == pytest.approx(2 * 0.85 * 0.015)
    assert s["efficiency_sys95_engine_map"] == pytest.approx(2 * 0.85 * 0.05)
    assert s["efficiency_sys95"] == pytest.approx(math.hypot(2 * 0.85 * 0.015, 2 * 0.85 * 0.05))
    assert math.isnan(point_systematic({"efficiency": math.nan}, 0.015, 0.05)["efficiency_sys95"])


def test_the_interval_is_the_truths_95_percent_range_asymmetric_and_clipped():
    """Monte Carlo of the world the interval describes: a true efficiency, read low by a driveline loss
    (uniform 0..L_max: a loss only lowers the reading), off by an unknown day's J1349 factor (uniform day)
    and by normal terms: the interval holds the truth ~95 % of the time, and is one-sided where a term is."""
    import numpy as np

    from dyno.analysis.air import uncorrected_factors
    from dyno.analysis.systematic import interval95

    eta, sym95, lmax = 0.7, 0.04, 0.04
    # the driveline alone: the interval extends upward only, to the loss bound
    lo, hi = interval95(eta, 0.0, None, lmax)
    assert lo == pytest.approx(eta, rel=2e-3) and hi == pytest.approx(eta / (1 - 0.975 * lmax), rel=2e-3)
    # every term: coverage by simulation (readings made from truths; the interval judged on the truth)
    rng = np.random.default_rng(7)
    q = np.asarray(uncorrected_factors())
    n = 1000
    cf = rng.choice(q, n)
    truth = 0.6 + 0.02 * rng.standard_normal(n)
    reading = truth * (1 - rng.uniform(0, lmax, n)) / cf + rng.normal(0, sym95 / 2, n)
    inside = [a <= t <= b for t, r in zip(truth, reading) for a, b in [interval95(r, sym95, q, lmax)]]
    assert 0.93 <= np.mean(inside) <= 0.975
    lo, hi = interval95(eta, sym95, q, lmax)
    assert hi - eta > 2 * (eta - lo)  # the day can only be this much worse, far more better
    assert interval95(0.95, sym95, q, lmax)[1] == 1.0  # never beyond what physics allows
    assert interval95(0.5, 0.02) == pytest.approx([0.48, 0.52])  # known air, no driveline: symmetric


def test_the_driveline_term_is_one_sided_in_u95_and_the_interval():
    s = point_systematic({"efficiency": 0.8, "efficiency_ci95": 0.007}, 0.015, 0.05, 0.002,
                         driveline_max_frac=0.04)
    assert s["efficiency_u95_terms"]["driveline"] == pytest.approx(0.8 * (1 / 0.96 - 1))
    lo, hi = s["efficiency_interval95"]
    assert hi - 0.8 > 0.8 - lo > 0  # extends further upward


def test_the_driveline_bound_is_the_chains_share_plus_the_bearings_drag_over_the_torque():
    from dyno.analysis.systematic import driveline_bound, interval_basis

    unc = {"driveline_loss_max_frac": 0.03, "driveline_drag_max_nm": 0.25}
    assert driveline_bound({"torque_secondary_nm": 25.0}, unc) == pytest.approx(0.04)
    assert driveline_bound({"torque_secondary_nm": 5.0}, unc) == pytest.approx(0.08)  # light load: the drag
    assert driveline_bound({"torque_secondary_nm": math.nan}, unc) == pytest.approx(0.03)
    assert driveline_bound({"torque_secondary_nm": 0.01}, unc) == 0.5
    assert interval_basis(unc, {"torque_secondary_nm": 5.0})["driveline_max_frac"] == pytest.approx(0.08)
    assert interval_basis({}, {"torque_secondary_nm": 5.0}) == {"air_factors": None, "driveline_max_frac": 0.0,
                                                               "wear_max_frac": 0.0}


def test_a_term_the_point_already_states_is_combined():
    base = point_systematic({"efficiency": 0.5, "efficiency_ci95": 0.01}, 0.015, 0.05)
    s = point_systematic({"efficiency": 0.5, "efficiency_ci95": 0.01, "efficiency_sys95_friction": 0.03}, 0.015, 0.05)
    assert s["efficiency_u95_terms"]["friction"] == 0.03
    assert s["efficiency_u95"] == pytest.approx(math.hypot(base["efficiency_u95"], 0.03))
    assert s["efficiency_interval95"][1] - 0.5 == pytest.approx(s["efficiency_u95"])


def test_the_engines_wear_is_one_sided_and_only_for_a_map_not_measured_on_it():
    """A worn engine only makes less than its map: the truth may lie above the reading, never further below."""
    sym = interval95(0.70, 0.10)
    worn = interval95(0.70, 0.10, wear_max_frac=0.14)
    assert worn[1] > sym[1] and worn[0] >= sym[0]  # the upper end moves out; the lower end no further down
    assert interval_basis({"engine_wear_max_frac": 0.14}, {})["wear_max_frac"] == 0.14
    p = {"efficiency": 0.7, "efficiency_ci95": 0.01, "torque_secondary_nm": 10.0}
    s = point_systematic(p, 0.016, 0.10, wear_max_frac=0.14)
    assert s["efficiency_u95_terms"]["engine_wear"] == pytest.approx(0.7 * (1 / 0.86 - 1))
    assert "engine_wear" not in point_systematic(p, 0.016, 0.10)["efficiency_u95_terms"]
