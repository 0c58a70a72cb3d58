"""The systematic part of a point's uncertainty, and adding back a driven-side loss."""

import math
from types import SimpleNamespace

import pytest

from dyno.analysis.efficiency import (DEFAULT_MAP_POWER_REL_UNC95, add_back_loss, calibration_slope_rel_unc95,
                                      efficiency_systematic95)


def test_calibration_slope_uncertainty_from_the_fit_or_from_r2():
    assert calibration_slope_rel_unc95(SimpleNamespace(slope_se_counts_per_nm=0.5, slope_counts_per_nm=100.0)) \
        == pytest.approx(0.01)
    # r^2 = 0.9998 over 12 samples: se/a = sqrt((1/r2 - 1)/10)
    cal = SimpleNamespace(r2=0.9998, n_samples=12, slope_counts_per_nm=108.0)
    assert calibration_slope_rel_unc95(cal) == pytest.approx(2 * math.sqrt((1 / 0.9998 - 1) / 10))
    # unknown count (imported thesis rows): the most conservative n - 2 = 1
    assert calibration_slope_rel_unc95(SimpleNamespace(r2=0.9998, n_samples=0, slope_counts_per_nm=108.0)) \
        == pytest.approx(2 * math.sqrt(1 / 0.9998 - 1))


def test_systematic_part_by_source_and_combined():
    cal = SimpleNamespace(r2=0.9998, n_samples=12, slope_counts_per_nm=108.0)
    s = efficiency_systematic95(0.88, cal, SimpleNamespace())
    assert s["efficiency_sys95_engine_map"] == pytest.approx(0.88 * DEFAULT_MAP_POWER_REL_UNC95)
    assert s["efficiency_sys95"] == pytest.approx(math.hypot(s["efficiency_sys95_calibration"],
                                                             s["efficiency_sys95_engine_map"]))
    s2 = efficiency_systematic95(0.88, cal, SimpleNamespace(power_rel_unc95=0.02))
    assert s2["efficiency_sys95_engine_map"] == pytest.approx(0.88 * 0.02)


def test_add_back_loss_propagates_both_uncertainties():
    eta, ci = add_back_loss(0.85, 0.008, 5000.0, 3000.0, 0.12, 0.05)
    w = 3000 * math.pi / 30
    assert eta == pytest.approx(0.85 + 0.12 * w / 5000)
    assert ci == pytest.approx(math.hypot(0.008, 0.05 * w / 5000))
