"""The systematic part of a point's uncertainty: calibration reproducibility and engine-map terms."""

import math

import pytest

from dyno.analysis.calibration import CalibrationEntry
from dyno.analysis.systematic import calibration_rel_u, point_systematic

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
