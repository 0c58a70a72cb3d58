"""Part-throttle engine maps: the `throttle` column, one curve per throttle; full-throttle files unchanged;
bad files refused in one line naming file, line and field; the shipped synthetic map is reproducible and
close to the simulated engine it was generated from (the host never calls the sim's model itself)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dyno.analysis.engine_map_range import NoThrottleCurve, OutOfMapRange
from dyno.analysis.engine_map import load_engine_map
from dyno.errors import ConfigError

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

REPO = Path(__file__).resolve().parents[2]
FULL = REPO / "calibration" / "engine_maps" / "baja-10hp-representative.csv"
PART = REPO / "calibration" / "engine_maps" / "baja-10hp-representative-part-throttle.csv"


def _write(tmp_path, text: str) -> Path:
    p = tmp_path / "map.csv"
    p.write_text(text)
    return p


def test_a_full_throttle_only_file_keeps_working_and_has_no_part_throttle(tmp_path):
    m = load_engine_map(FULL)
    assert m.throttles == [1.0] and m.at_throttle(1.0) is m and m.at_throttle(0.998) is m
    with pytest.raises(NoThrottleCurve) as e:
        m.at_throttle(0.6)
    assert "throttle 0.60" in str(e.value) and isinstance(e.value, OutOfMapRange)


def test_throttle_column_gives_one_curve_per_throttle(tmp_path):
    p = _write(tmp_path, "# a map\nthrottle,rpm,torque_nm\n1,2000,18\n1,3000,17\n1,3800,0\n"
                         "0.5,2000,18\n0.5,2500,10\n0.5,2600,0\n")
    m = load_engine_map(p)
    assert m.throttles == [0.5, 1.0]
    assert m.torque_nm(2500) == pytest.approx(17.5, abs=0.3)  # the full curve, as a 2-column file would give
    half = m.at_throttle(0.5)
    assert half.torque_nm(2500) == 10.0 and half.rpm_max == 2600 and half.throttle_frac == 0.5
    assert m.at_throttle(0.503) is half  # within the tolerance ...
    with pytest.raises(NoThrottleCurve):  # ... but never a blend of two curves
        m.at_throttle(0.75)
    with pytest.raises(OutOfMapRange):  # a curve refuses to extrapolate, like the full one
        half.torque_nm(2700)
    assert m.metadata()["throttles"] == [0.5, 1.0]
    amb = m.at_ambient(35.0, 90.0)  # J1349 applies to every curve: the full one divided by the factor, a
    # part-throttle one's fuelled torque scaled alike, its friction not (dyno.analysis.part_throttle_air)
    from dyno.analysis.part_throttle_air import part_throttle_at_ambient

    expect, _ = part_throttle_at_ambient([2500], [10.0], [m.torque_nm(2500)], amb.j1349_factor)
    assert amb.at_throttle(0.5).torque_nm(2500) == pytest.approx(expect[0])
    assert amb.torque_nm(2500) == pytest.approx(m.torque_nm(2500) / amb.j1349_factor)
    assert amb.at_throttle(0.5).torque_nm(2500) < 10.0 / amb.j1349_factor  # a hot, thin day: the friction stays


@pytest.mark.parametrize("body, field", [
    ("throttle,rpm,torque_nm\n0.5,2000,18\n0.5,2500,10\n", "throttle"),  # no full-throttle curve
    ("throttle,rpm,torque_nm\n1,2000,18\n1,3000,17\n0.5,2000,x\n0.5,2500,1\n", "line 4, field torque_nm"),
    ("throttle,rpm,torque_nm\n1,2000,18\n1,3000,17\n1.5,2000,3\n1.5,2500,1\n", "line 4, field throttle"),
    ("throttle,rpm,torque_nm\n1,2000,18\n0.5,2000,3\n0.5,2500,1\n1,3000,17\n", "line 5, field throttle"),
    ("throttle,rpm,torque_nm\n1,2000,18\n1,3000,17\n0.5,2000,3\n", "line 4, field throttle"),  # 1 row
    ("throttle,rpm,torque_nm\n1,2000,18\n1,3000,17\n0.5,2500,3\n0.5,2000,1\n", "line 5, field rpm"),
    ("rpm,throttle,torque_nm\n2000,1,18\n3000,1,17\n", "header"),
])
def test_bad_part_throttle_files_name_file_line_and_field(tmp_path, body, field):
    p = _write(tmp_path, body)
    with pytest.raises(ConfigError) as e:
        load_engine_map(p)
    msg = str(e.value)
    assert str(p) in msg and field in msg and "\n" not in msg


def test_shipped_synthetic_map_is_reproducible_and_follows_the_sim(tmp_path):
    out = tmp_path / "pt.csv"
    r = subprocess.run([sys.executable, "-m", "dyno.sim.part_throttle_map", "--out", out],
                       capture_output=True, text=True, timeout=60, cwd=REPO)
    assert r.returncode == 0, r.stderr
    assert out.read_text() == PART.read_text()  # the shipped file is what the script writes
    m, full = load_engine_map(PART), load_engine_map(FULL)
    assert np.array_equal(m.rpm, full.rpm) and np.array_equal(m.torque_nm_knots, full.torque_nm_knots)
    assert m.throttles == [0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    # The host's interpolation of the grid against the model, independently evaluated here.
    from dyno.sim.physics import RigModel
    from dyno.sim.rig_params import RigParams

    eng = RigModel(RigParams(ideal=True)).engine  # the nominal engine (a seed's own deviates: dyno.sim.world)
    for u in m.throttles[:-1]:
        c = m.at_throttle(u)
        n = np.linspace(c.rpm_min, c.rpm_max, 1500)
        truth = np.array([max(0.0, eng.torque_nm(x, u, True)) for x in n])
        assert np.max(np.abs(c.torque_nm(n) - truth)) < 0.02, u
        assert c.torque_nm(c.rpm_max) == 0.0  # the curve ends where the net torque reaches 0
    bad = subprocess.run([sys.executable, "-m", "dyno.sim.part_throttle_map", "--out", tmp_path / "x.csv",
                          "--throttles", "0.5,abc"], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and "Traceback" not in bad.stderr
    assert not (tmp_path / "x.csv").exists()
