"""Engine map loading, PCHIP interpolation, range refusal and SAE J1349."""

import hashlib
import math
from pathlib import Path

import numpy as np
import pytest

from dyno.analysis.engine_map import W_PER_HP, EngineMap, load_engine_map, load_legacy_engine_map
from dyno.analysis.engine_map_range import OutOfMapRange
from dyno.analysis.air import dry_air_pressure_kpa, j1349_correction_factor, saturation_vapour_pressure_kpa
from dyno.datapaths import legacy_data_dir, legacy_data_missing
from dyno.errors import ConfigError

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

ROOT = Path(__file__).resolve().parents[2]
REPRESENTATIVE = ROOT / "calibration/engine_maps/baja-10hp-representative.csv"
LEGACY = legacy_data_dir() / "engine_power_RPM.csv"

RPM = np.array([1500, 2000, 2500, 3000, 3400, 3600, 3800.0])
TORQUE = np.array([15.0, 17.5, 18.6, 18.0, 16.3, 13.0, 3.0])  # rise, plateau, governor droop


def _write(tmp_path, text, name="map.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_analysis_pchip_hits_knots_is_monotone_between_and_never_overshoots():
    m = EngineMap(RPM, TORQUE)
    assert m.torque_nm(RPM) == pytest.approx(TORQUE)
    for a, b, ta, tb in zip(RPM[:-1], RPM[1:], TORQUE[:-1], TORQUE[1:]):
        x = np.linspace(a, b, 201)
        y = m.torque_nm(x)
        assert np.all(y >= min(ta, tb) - 1e-9) and np.all(y <= max(ta, tb) + 1e-9)  # no overshoot
        d = np.diff(y)
        assert np.all(d >= -1e-12) if tb >= ta else np.all(d <= 1e-12)  # monotone like the data
    flat = EngineMap([1000, 2000, 3000, 4000], [10, 10, 10, 5])
    assert flat.torque_nm(np.linspace(1000, 3000, 50)) == pytest.approx(10.0)  # no ringing


def test_analysis_power_and_its_derivative():
    m = EngineMap(RPM, TORQUE)
    assert m.power_w(3000) == pytest.approx(18.0 * 3000 * 2 * math.pi / 60)
    n = np.array([1700.0, 2600.0, 3300.0, 3700.0])
    h = 1e-3
    fd = (m.power_w(n + h) - m.power_w(n - h)) / (2 * h)
    assert m.dpower_drpm(n) == pytest.approx(fd, rel=1e-6)
    assert isinstance(m.power_w(2000), float)


def test_analysis_refuses_out_of_range_and_names_rpm_and_range():
    m = EngineMap(RPM, TORQUE, source="maps/x.csv")
    assert m.covers(1500) and m.covers([1500, 3800]) and not m.covers(3800.5)
    assert not m.covers(math.nan)
    for bad in (1499.9, 3900.0, [2000, 4000]):
        with pytest.raises(OutOfMapRange) as err:
            m.power_w(bad)
        msg = str(err.value)
        assert "1500" in msg and "3800" in msg and "maps/x.csv" in msg
    with pytest.raises(OutOfMapRange, match="4000"):
        m.dpower_drpm([2000, 4000])
    with pytest.raises(ValueError):  # OutOfMapRange is a ValueError for generic callers
        m.torque_nm(math.nan)


def test_analysis_engine_map_constructor_validates():
    with pytest.raises(ValueError, match="strictly increasing"):
        EngineMap([1000, 1000, 2000], [1, 2, 3])
    with pytest.raises(ValueError, match="at least 2"):
        EngineMap([1000], [1])
    with pytest.raises(ValueError, match="finite"):
        EngineMap([1000, 2000], [1, math.inf])


@pytest.mark.parametrize("header, scale", [
    ("rpm,torque_nm", None), ("rpm,power_hp", W_PER_HP), ("rpm,power_kw", 1000.0)])
def test_analysis_load_each_header_gives_same_torque(tmp_path, header, scale):
    p_w = TORQUE * RPM * 2 * math.pi / 60
    vals = TORQUE if scale is None else p_w / scale
    text = "# comment line\n" + header + "\n" + "".join(f"{float(n)!r},{float(v)!r}\n" for n, v in zip(RPM, vals))
    p = _write(tmp_path, text)
    m = load_engine_map(p)
    assert m.torque_nm(RPM) == pytest.approx(TORQUE, rel=1e-12)
    assert m.source == str(p) and m.sha256 == hashlib.sha256(p.read_bytes()).hexdigest()
    assert m.metadata()["sha256"] == m.sha256 and m.metadata()["j1349_factor"] == 1.0


def test_analysis_load_shipped_representative_map():
    m = load_engine_map(REPRESENTATIVE)
    assert m.rpm_min == 1500 and m.rpm_max == 3850
    assert m.torque_nm(2400) == pytest.approx(18.6)


@pytest.mark.skipif(not LEGACY.exists(), reason=legacy_data_missing() or f"{LEGACY} missing")
def test_analysis_load_legacy_thesis_map_in_place():
    before = LEGACY.read_bytes()
    m = load_legacy_engine_map(LEGACY)
    assert LEGACY.read_bytes() == before
    assert m.power_w(3348.62) / W_PER_HP == pytest.approx(7.70)
    assert m.rpm_min == pytest.approx(1548.76) and m.rpm_max == pytest.approx(3798.68)
    with pytest.raises(ConfigError, match="load_legacy_engine_map"):
        load_engine_map(LEGACY)  # headerless: units must not be guessed


@pytest.mark.parametrize("text, where", [
    ("rpm,power_ps\n1000,1\n2000,2\n", "line 1 (header)"),
    ("rpm,torque_nm\n1000,10\n2000\n", "line 3"),
    ("rpm,torque_nm\n1000,10\n2000,abc\n", "line 3, field torque_nm"),
    ("rpm,torque_nm\n1000,10\n2000,nan\n", "line 3, field torque_nm"),
    ("rpm,torque_nm\n1000,10\n2000,-1\n", "line 3, field torque_nm"),
    ("# c\nrpm,torque_nm\n1000,10\n2000,12\n1900,12\n", "line 5, field rpm"),
    ("rpm,torque_nm\n1000,10\n1000,12\n", "line 3, field rpm"),
    ("rpm,torque_nm\n1000,10\n", "data rows"),
    ("# only a comment\n", "header"),
])
def test_analysis_malformed_engine_map_names_file_and_row(tmp_path, text, where):
    p = _write(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        load_engine_map(p)
    assert str(p) in str(err.value) and where in str(err.value)


def test_analysis_malformed_legacy_map(tmp_path):
    p = _write(tmp_path, "1548.76,3.40\n1500,3.9\n", "engine_power_RPM.csv")
    with pytest.raises(ConfigError, match=r"engine_power_RPM.csv: line 2, field rpm"):
        load_legacy_engine_map(p)
    with pytest.raises(ConfigError, match="missing"):
        load_legacy_engine_map(tmp_path / "missing.csv")


def test_analysis_j1349_is_one_at_reference_and_moves_the_right_way():
    assert j1349_correction_factor(25.0, 99.0) == pytest.approx(1.0, abs=1e-12)
    # hotter or thinner air: engine makes less than standard -> CF > 1
    assert j1349_correction_factor(35.0, 99.0) > 1.0
    assert j1349_correction_factor(25.0, 90.0) > 1.0
    assert j1349_correction_factor(10.0, 101.0) < 1.0
    # 10 % less dry air -> ~1.176 * 0.111 = 13 % correction
    assert j1349_correction_factor(25.0, 90.0) == pytest.approx(1.176 * 99 / 90 - 0.176)
    with pytest.raises(ValueError, match="kPa"):
        j1349_correction_factor(25.0, 99000.0)  # Pa by mistake


def test_analysis_at_ambient_divides_standard_power_and_does_not_compound():
    m = EngineMap(RPM, TORQUE, source="x", sha256="ab")
    cf = j1349_correction_factor(35.0, 95.0)
    hot = m.at_ambient(35.0, 95.0)
    assert hot.power_w(3000) == pytest.approx(m.power_w(3000) / cf)
    assert hot.power_w(3000) < m.power_w(3000)
    assert hot.sha256 == "ab" and hot.j1349_factor == pytest.approx(cf) and hot.ambient == (35.0, 95.0)
    again = hot.at_ambient(25.0, 99.0)
    assert again.power_w(3000) == pytest.approx(m.power_w(3000))


def test_analysis_dry_air_pressure_from_humidity():
    assert saturation_vapour_pressure_kpa(100.0) == pytest.approx(101.3, rel=0.005)  # boiling
    assert saturation_vapour_pressure_kpa(20.0) == pytest.approx(2.339, rel=0.002)
    assert dry_air_pressure_kpa(100.0, 25.0, 0.0) == 100.0
    assert dry_air_pressure_kpa(100.0, 25.0, 100.0) == pytest.approx(100.0 - 3.169, abs=0.01)
    with pytest.raises(ValueError, match="relative_humidity_pct"):
        dry_air_pressure_kpa(100.0, 25.0, 0.5 * 200 + 1)
