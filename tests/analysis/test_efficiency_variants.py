"""Issue 39: every efficiency variant K carries ``K_interval95`` with all its terms, and a value outside 0…1 is a
fault naming K (``channel: K``) that marks the point invalid, as the main efficiency's does."""

from __future__ import annotations

import math

import pytest

from dyno.analysis.coastdown import driven_loss_keys
from dyno.analysis.systematic import point_systematic
from dyno.analysis.zero_check import corrected_point_keys

pytestmark = pytest.mark.quick

UNC = {"air_day": None, "driveline_loss_max_frac": 0.04}


def _point(eff=0.8, torque=15.0):
    p = {"efficiency": eff, "efficiency_ci95": 0.007, "torque_secondary_nm": torque, "rpm_secondary": 3000.0,
         "power_in_w": 5000.0, "host_t_start_s": 10.0, "host_t_end_s": 14.0, "faults": [], "valid": True}
    p.update(point_systematic(p, 0.016, 0.05, 0.002, driveline_max_frac=0.04))
    return p


def _loss(a_nm):
    cov = [[1e-4, 0, 0], [0, 0, 0], [0, 0, 0]]
    return {"loss_fit": {"coefficients": {"a_nm": a_nm, "b_nm_per_rad_s": 0.0, "c_nm_per_rad_s2": 0.0},
                         "covariance": cov, "rpm_min": 1000.0, "rpm_max": 6000.0}, "seen_nm": 0.0}


def test_the_loss_corrected_interval_has_every_term_but_the_driveline_bound():
    p = _point()
    k = driven_loss_keys(p, _loss(0.3), UNC)
    e, (lo, hi) = k["efficiency_loss_corrected"], k["efficiency_loss_corrected_interval95"]
    assert e == pytest.approx(0.8 + 0.3 * 3000 * math.pi / 30 / 5000)
    # the map and calibration terms are there (its old ±95 % was the statistics and the loss alone) ...
    t = p["efficiency_u95_terms"]
    assert (hi - lo) / 2 == pytest.approx(math.hypot(k["efficiency_loss_corrected_ci95"],
                                                     *(e / 0.8 * t[n] for n in ("calibration", "engine_map", "air"))),
                                          rel=1e-6)
    # ... and the driveline's one-sided bound is replaced by the measured loss: symmetric about the figure
    assert hi - e == pytest.approx(e - lo)
    assert p["efficiency_interval95"][1] - 0.8 > 0.8 - p["efficiency_interval95"][0]  # (the uncorrected's is not)
    assert "faults" not in k


def test_a_loss_corrected_efficiency_above_one_is_a_fault_naming_it():
    k = driven_loss_keys(_point(0.95), _loss(3.0), UNC)
    assert k["efficiency_loss_corrected"] > 1.0 and k["valid"] is False
    assert [f["channel"] for f in k["faults"]] == ["efficiency_loss_corrected"]
    assert k["efficiency_loss_corrected_interval95"][1] <= 1.0


def test_the_zero_corrected_efficiency_has_its_interval_and_range_fault():
    check = {"before": {"torque_nm": 0.0, "t_mid_s": 0.0}, "after": {"torque_nm": 0.4, "t_mid_s": 24.0},
             "drift_nm": 0.4}
    p = _point()
    k = corrected_point_keys(p, check, UNC)
    ez = k["efficiency_zero_corrected"]
    assert ez == pytest.approx(0.8 * (15.0 - 0.2) / 15.0)
    lo, hi = k["efficiency_zero_corrected_interval95"]
    plo, phi = p["efficiency_interval95"]
    assert lo == pytest.approx(plo * ez / 0.8, rel=0.01) and hi == pytest.approx(phi * ez / 0.8, rel=0.01)
    assert "faults" not in k
    bad = corrected_point_keys(_point(0.8, torque=0.15), check, UNC)  # a zero drift bigger than the torque
    assert bad["efficiency_zero_corrected"] < 0 and bad["valid"] is False
    assert bad["faults"][-1]["channel"] == "efficiency_zero_corrected"


def test_the_engine_maps_figure_beside_the_input_path_keeps_its_interval_and_range_fault():
    import numpy as np

    from dyno.analysis.input_torque import InputChannel, input_point, input_systematic
    from dyno.analysis.calibration_history import CalibrationEntry
    from dyno.protocol import v1

    cal = CalibrationEntry(date="2026-01-01", slope_counts_per_nm=100.0, intercept_counts=30000.0, r2=0.9999, n_samples=0)
    ch = InputChannel(cal, 0.01, 0.0, 0.02)

    class Streams:
        def input_window(self, t0, t1):
            codes = np.full(200, 30000 + 100 * 17, dtype=np.int64) + np.arange(200) % 3
            return np.arange(200), codes, np.zeros(200, dtype=np.int64) & v1.ADC_STATUS_ERR

    p = _point(1.08)  # the map says more power out than in: the map cannot be right at this point
    p.update(t_start_us=0, t_end_us=4_000_000, rpm_primary=3000.0, torque_secondary_nm=15.0)
    out = input_point(Streams(), p, ch)
    assert out["efficiency_engine_map_interval95"] == p["efficiency_interval95"]
    assert [f["channel"] for f in out["faults"]] == ["efficiency_engine_map"] and out["valid"] is False
    p.update(out)
    s = input_systematic(p, 0.016, ch, 0.04)
    lo, hi = s["efficiency_interval95"]
    assert lo < p["efficiency"] < hi <= 1.0 and s["efficiency_u95_terms"]["driveline"] > 0
