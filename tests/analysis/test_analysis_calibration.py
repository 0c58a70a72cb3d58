"""Torque calibration: fit, refusals, history file atomicity and validation."""

import os
from pathlib import Path

import numpy as np
import pytest

from dyno.analysis.calibration_history import (HISTORY_COLUMNS, CalibrationEntry, CalibrationRejected, NoCalibration,
                                               append_entry, latest, load_history, load_legacy_cal_values)
from dyno.analysis.calibration import fit_calibration, torque_from_mass
from dyno.datapaths import legacy_data_dir, legacy_data_missing
from dyno.errors import ConfigError

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "calibration/torque_calibration.csv"
LEGACY = legacy_data_dir() / "cal_values.csv"

TRUE_SLOPE, TRUE_INTERCEPT = 108.19, 35145.0  # thesis eq 9.1


def _entry(**kw):
    base = dict(date="2024-05-01", slope_counts_per_nm=108.0, intercept_counts=35100.0, r2=0.9995,
                n_samples=4000, lever_arm_m=0.127, note="bench")
    base.update(kw)
    return CalibrationEntry(**base)


def _synthetic(seed=1, masses=(0, 1, 2, 3, 5, 7, 10, 14, 20), noise_counts=4.0, n=500):
    rng = np.random.default_rng(seed)
    t = torque_from_mass(np.array(masses, float), 0.127)
    # per-step offset (rope seating, bridge drift) + within-step ripple
    offsets = rng.normal(0.0, noise_counts, len(t))
    raw = [TRUE_SLOPE * ti + TRUE_INTERCEPT + o + 30 * np.sin(np.linspace(0, 60, n)) for ti, o in
           zip(t, offsets)]
    return t, raw


# ---- fit -------------------------------------------------------------------

@pytest.mark.parametrize("seed", [1, 2, 3])
def test_analysis_fit_recovers_known_line_within_two_standard_errors(seed):
    t, raw = _synthetic(seed)
    fit = fit_calibration(t, raw)
    assert abs(fit.slope_counts_per_nm - TRUE_SLOPE) < 2 * fit.slope_se_counts_per_nm
    assert abs(fit.intercept_counts - TRUE_INTERCEPT) < 2 * fit.intercept_se_counts
    assert fit.r2 > 0.999 and fit.n_samples == 500 * len(t) and fit.n_distinct_loads == len(t)
    assert fit.within_step_sd_counts == pytest.approx(30 / np.sqrt(2), rel=0.1)
    assert fit.nonlinearity_pct_fs == pytest.approx(
        100 * np.max(np.abs(fit.residuals_counts)) / (fit.slope_counts_per_nm * np.ptp(t)))


def test_analysis_fit_means_with_counts_equals_raw():
    t, raw = _synthetic(4)
    a = fit_calibration(t, raw)
    b = fit_calibration(t, [r.mean() for r in raw], n_samples=[len(r) for r in raw])
    assert b.slope_counts_per_nm == pytest.approx(a.slope_counts_per_nm, rel=1e-12)
    assert b.intercept_se_counts == pytest.approx(a.intercept_se_counts, rel=1e-9)
    assert b.n_samples == a.n_samples and b.within_step_sd_counts is None
    # 2-D raw array is accepted too
    c = fit_calibration(t, np.vstack(raw))
    assert c.slope_counts_per_nm == pytest.approx(a.slope_counts_per_nm, rel=1e-12)


def test_analysis_fit_standard_errors_match_textbook_formula():
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    c = np.array([1.0, 3.1, 4.9, 7.2, 8.8]) + 100
    fit = fit_calibration(t, c, r2_min=0.9)
    ref_slope, ref_int = np.polyfit(t, c, 1)
    _, cov = np.polyfit(t, c, 1, cov="unscaled")
    s2 = np.sum(fit.residuals_counts ** 2) / 3
    assert fit.slope_counts_per_nm == pytest.approx(ref_slope)
    assert fit.intercept_counts == pytest.approx(ref_int)
    assert fit.slope_se_counts_per_nm == pytest.approx(np.sqrt(cov[0, 0] * s2))
    assert fit.intercept_se_counts == pytest.approx(np.sqrt(cov[1, 1] * s2))
    assert fit.cov_slope_intercept == pytest.approx(cov[0, 1] * s2)


def test_analysis_fit_refuses_two_distinct_loads():
    t = [0.0, 5.0, 5.0, 0.0]
    with pytest.raises(CalibrationRejected, match="2 distinct load"):
        fit_calibration(t, [35145, 35686, 35687, 35146])


def test_analysis_fit_refuses_low_r2_and_negative_slope():
    t = np.array([0, 2, 4, 6, 8.0])
    c = TRUE_INTERCEPT + TRUE_SLOPE * t + np.array([0, 15, -15, 15, -10])  # R^2 ~ 0.998
    with pytest.raises(CalibrationRejected, match=r"R\^2 = 0\.99\d+ is below the required 0\.999"):
        fit_calibration(t, c)
    assert 0.99 < fit_calibration(t, c, r2_min=0.99).r2 < 0.999
    with pytest.raises(CalibrationRejected, match="not positive"):
        fit_calibration(t, TRUE_INTERCEPT - TRUE_SLOPE * t)
    assert issubclass(CalibrationRejected, ValueError)


def test_analysis_fit_hysteresis_from_direction_flags():
    t = np.array([0, 2, 4, 6, 4, 2, 0.0])
    c = TRUE_INTERCEPT + TRUE_SLOPE * t
    c[4] += 12.0  # unloading reads high at 4 N·m (friction in the bearings)
    c[5] += 5.0
    fit = fit_calibration(t, c, direction=["up", "up", "up", "up", "down", "down", -1])
    assert fit.hysteresis_counts == pytest.approx(12.0)
    assert fit.hysteresis_pct_fs == pytest.approx(12.0 / (fit.slope_counts_per_nm * 6) * 100)
    assert fit_calibration(t, c).hysteresis_counts is None
    with pytest.raises(ValueError, match="direction"):
        fit_calibration(t, c, direction=["up"] * 6 + ["sideways"])


def test_analysis_torque_from_mass_uses_rope_radius_and_gear_ratio():
    # 10 kg on 0.1 m: 9.80665 N·m on the brake shaft, x 32/61 on the secondary
    assert torque_from_mass(10.0, 0.1) == pytest.approx(9.80665 * 32 / 61)
    assert torque_from_mass([0, 10], 0.1, 1.0, g=9.8).tolist() == pytest.approx([0, 9.8])
    with pytest.raises(ValueError, match="lever_arm_m"):
        torque_from_mass(1.0, 0.0)


def test_analysis_fit_to_entry_converts_counts_back_to_torque():
    t, raw = _synthetic(5)
    e = fit_calibration(t, raw).to_entry("2024-05-01", lever_arm_m=0.127, note="x")
    assert e.torque_secondary_nm(e.counts(12.5)) == pytest.approx(12.5)
    counts = np.array([35145.0, 35145.0 + 108.19 * 3])
    assert e.torque_secondary_nm(counts).shape == (2,)
    assert CalibrationEntry.from_dict(e.to_dict()) == e


# ---- entry and history ---------------------------------------------------------

def test_analysis_entry_validates_fields():
    with pytest.raises(ValueError, match="slope_counts_per_nm"):
        _entry(slope_counts_per_nm=0.0)
    with pytest.raises(ValueError, match="r2"):
        _entry(r2=1.2)
    with pytest.raises(ValueError, match="date"):
        _entry(date="18/04/2019")
    with pytest.raises(ValueError, match="missing"):
        CalibrationEntry.from_dict({"date": "2024-01-01"})


def test_analysis_shipped_history_is_the_thesis_calibration():
    hist = load_history(SHIPPED)
    assert len(hist) == 4
    assert all("thesis rig 2019 (imported)" in e.note for e in hist)
    cur = latest(hist)
    assert cur.slope_counts_per_nm == pytest.approx(108.19, abs=0.01)  # eq 9.1
    assert cur.intercept_counts == pytest.approx(35145, abs=1)
    assert cur.gear_ratio_brake_per_secondary == pytest.approx(32 / 61)


@pytest.mark.skipif(not LEGACY.exists(), reason=legacy_data_missing() or f"{LEGACY} missing")
def test_analysis_legacy_cal_values_match_shipped_history():
    legacy = load_legacy_cal_values(LEGACY)
    shipped = load_history(SHIPPED)
    assert [(e.slope_counts_per_nm, e.intercept_counts, e.r2) for e in legacy] == \
        [(e.slope_counts_per_nm, e.intercept_counts, e.r2) for e in shipped]


def test_analysis_latest_by_date_then_file_order():
    a, b, c = _entry(date="2024-05-02", note="a"), _entry(date="2024-05-01", note="b"), \
        _entry(date="2024-05-02", note="c")
    assert latest([a, b, c]).note == "c"
    assert latest([a, b]).note == "a"
    with pytest.raises(NoCalibration):
        latest([])


def test_analysis_append_keeps_old_rows_and_round_trips(tmp_path):
    p = tmp_path / "cal.csv"
    p.write_bytes(SHIPPED.read_bytes())
    old = p.read_bytes()
    new = _entry(note='with "quotes", commas')
    append_entry(p, new)
    assert p.read_bytes().startswith(old)
    hist = load_history(p)
    assert len(hist) == 5 and hist[-1] == new and latest(hist) == new
    assert [f.name for f in tmp_path.iterdir()] == ["cal.csv"]  # no temp file left


def test_analysis_append_creates_missing_file(tmp_path):
    p = tmp_path / "new.csv"
    append_entry(p, _entry(lever_arm_m=None))
    assert p.read_text().splitlines()[0] == ",".join(HISTORY_COLUMNS)
    assert load_history(p)[0].lever_arm_m is None


def test_analysis_append_is_atomic_when_replace_fails(tmp_path, monkeypatch):
    p = tmp_path / "cal.csv"
    p.write_bytes(SHIPPED.read_bytes())
    before = p.read_bytes()

    def boom(src, dst):
        raise OSError("disk pulled")

    monkeypatch.setattr(os, "replace", boom)  # (dyno.fileio.write_atomic replaces)
    with pytest.raises(OSError, match="disk pulled"):
        append_entry(p, _entry())
    assert p.read_bytes() == before
    assert [f.name for f in tmp_path.iterdir()] == ["cal.csv"]


def test_analysis_append_refuses_malformed_file_and_leaves_it_byte_identical(tmp_path):
    p = tmp_path / "cal.csv"
    text = SHIPPED.read_text().replace("110.709693655", "11O.7", 1)  # letter O typo
    p.write_text(text)
    before = p.read_bytes()
    mtime = os.stat(p).st_mtime_ns
    with pytest.raises(ConfigError) as err:
        append_entry(p, _entry())
    assert p.read_bytes() == before and os.stat(p).st_mtime_ns == mtime
    assert str(p) in str(err.value) and "line 3" in str(err.value)
    assert "slope_counts_per_nm" in str(err.value)


@pytest.mark.parametrize("mutate, where", [
    (lambda s: s.replace("date,", "when,", 1), "line 1 (header)"),
    (lambda s: s.replace("0.999897300325", "1.5"), "line 3, field r2"),
    (lambda s: s.replace("0.999897300325", "nan"), "line 3, field r2"),
    (lambda s: s.replace("2019-04-18,112", "April 2019,112"), "line 4, field date"),
    (lambda s: s.replace(",0,,", ",-1,,", 1), "line 2, field n_samples"),
    (lambda s: s.replace(",0,,", ",2.5,,", 1), "line 2, field n_samples"),
    (lambda s: s.replace("0,,0.52", "0,-0.1,0.52", 1), "line 2, field lever_arm_m"),
    (lambda s: s.replace(",0.5245901639344263,", ",inf,", 1), "line 2, field gear_ratio"),
    (lambda s: s.replace("108.188097293", "-108.2"), "line 5, field slope_counts_per_nm"),
    (lambda s: s + "2024-01-01,1,2\n", "line 6"),
])
def test_analysis_malformed_history_names_file_line_and_field(tmp_path, mutate, where):
    p = tmp_path / "bad.csv"
    p.write_text(mutate(SHIPPED.read_text()))
    with pytest.raises(ConfigError) as err:
        load_history(p)
    assert str(p) in str(err.value) and where in str(err.value)


def test_analysis_missing_history_is_config_error(tmp_path):
    with pytest.raises(ConfigError, match="missing.csv"):
        load_history(tmp_path / "missing.csv")


def test_analysis_malformed_legacy_cal_values(tmp_path):
    p = tmp_path / "cal_values.csv"
    p.write_text("slope,intercept,r2\n")
    with pytest.raises(ConfigError, match=r"line 1, field slope_counts_per_nm"):
        load_legacy_cal_values(p)
    p.write_text("108.1,35000,0.999\n108.1,35000\n")
    with pytest.raises(ConfigError, match=r"cal_values.csv: line 2: 3 numbers"):
        load_legacy_cal_values(p)
    p.write_text("108.1,35000,0.999\n\n")
    e = load_legacy_cal_values(p, date="2020-01-01")
    assert e[0].date == "2020-01-01" and e[0].n_samples == 0 and e[0].lever_arm_m is None
