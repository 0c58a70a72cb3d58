"""Torque zero checks (pure part)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from dyno.analysis.zero_check import corrected_point_keys, drift_check, zero_at, zero_reading

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

CAL = SimpleNamespace(slope_counts_per_nm=100.0, intercept_counts=30000.0,
                      torque_secondary_nm=lambda c: (c - 30000.0) / 100.0)


def test_zero_reading_is_the_mean_through_the_calibration_with_an_honest_interval():
    rng = np.random.default_rng(1)
    codes = np.round(30010 + 85 * rng.standard_normal(500)).astype(int)
    z = zero_reading(codes, np.zeros(500, dtype=int), CAL)
    assert z["torque_nm"] == pytest.approx(0.10, abs=0.05)
    assert 0.03 < z["ci95_nm"] < 0.2
    # error-flagged and rail conversions are not averaged in
    codes[:50] = 0
    status = np.zeros(500, dtype=int)
    status[50:100] = 0x20
    assert zero_reading(codes, status, CAL)["n_adc"] == 400


def test_drift_flagged_only_beyond_the_limit_and_the_noise():
    b = {"torque_nm": 0.0, "ci95_nm": 0.05, "t_mid_s": 0.0}
    assert not drift_check(b, {"torque_nm": 0.1, "ci95_nm": 0.05, "t_mid_s": 100.0}, 0.15)["flagged"]
    d = drift_check(b, {"torque_nm": 0.5, "ci95_nm": 0.05, "t_mid_s": 100.0}, 0.15)
    assert d["flagged"] and d["drift_nm"] == pytest.approx(0.5) and "drifted" in d["note"]
    noisy = drift_check(b, {"torque_nm": 0.2, "ci95_nm": 0.5, "t_mid_s": 100.0}, 0.15)
    assert not noisy["flagged"]
    missing = drift_check(b, {"torque_nm": math.nan, "ci95_nm": math.nan, "why": "the secondary turns"}, 0.15)
    assert not missing["flagged"] and "after the last point" in missing["note"]


def test_linear_correction_of_a_point():
    chk = drift_check({"torque_nm": 0.0, "ci95_nm": 0.05, "t_mid_s": 0.0},
                      {"torque_nm": 1.0, "ci95_nm": 0.05, "t_mid_s": 100.0}, 0.15)
    assert zero_at(chk, 50.0) == pytest.approx(0.5)
    keys = corrected_point_keys({"host_t_start_s": 40.0, "host_t_end_s": 60.0, "torque_secondary_nm": 20.5,
                                 "efficiency": 0.82}, chk)
    assert keys["torque_secondary_zero_corrected_nm"] == pytest.approx(20.0)
    assert keys["efficiency_zero_corrected"] == pytest.approx(0.82 * 20.0 / 20.5)
