"""dyno export --format parquet|mdf4: read back with the same library, equal to the run's streams and points."""

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dyno.session.root import RunSpec, run_test
from dyno.control.api import TestPlan as Plan
from dyno.library.exports import POINT_UNITS
from dyno.runlog.replay import replay
from dyno.runlog.reader import load_run

REPO = Path(__file__).resolve().parents[2]
QUICK_PLAN = replace(Plan(), max_measure_s=3.0, warmup_s=2.0, target_points=4)


def _dyno(*args, env_extra=None, pythonpath=None):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([*(pythonpath or []), str(REPO)]), **(env_extra or {}))
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO, env=env, timeout=300)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("exp") / "run"
    res = run_test(RunSpec(sim=True, seed=7, out_dir=out, plan=QUICK_PLAN))
    assert len(res["points"]) >= 2
    return out


def _check(back, run_dir):
    run = load_run(run_dir)
    s = run.streams
    assert np.array_equal(back["primary_edges"], np.frombuffer(s.edges[1], dtype=np.int64))
    assert np.array_equal(back["secondary_edges"], np.frombuffer(s.edges[2], dtype=np.int64))
    assert np.array_equal(back["adc_t_us"], np.frombuffer(s.adc_t, dtype=np.int64))
    assert np.array_equal(back["adc_code"], np.frombuffer(s.adc_code, dtype=np.uint16))
    assert np.array_equal(back["adc_status"], np.frombuffer(s.adc_status, dtype=np.uint8))
    assert len(back["primary_edges"]) > 100 and len(back["adc_code"]) > 100
    points = replay(run_dir)["points"]
    assert len(back["points"]) == len(points) == len(run.points)
    for got, want in zip(back["points"], points):
        for k in POINT_UNITS:
            w = want.get(k)
            w = float(w) if w is not None else np.nan
            assert float(got[k]) == pytest.approx(w, rel=1e-12, nan_ok=True), k
    # the live points too (replay reproduces them exactly)
    assert [float(p["efficiency"]) for p in back["points"]] == pytest.approx([p["efficiency"] for p in run.points])
    assert back["units"]["point_rpm_secondary"] == "rpm" and back["units"]["point_torque_secondary_nm"] == "N·m"
    assert back["units"]["point_power_out_w"] == "W" and back["units"]["point_duration_s"] == "s"
    assert "dyno.meta" in back["metadata"] and "cvtech-stock" in back["metadata"]["dyno.tune"]


def test_parquet_round_trip(run_dir, tmp_path):
    pytest.importorskip("pyarrow", reason="pyarrow (the [export] extra) is not installable here")
    from dyno.library.exports import read_parquet

    out = tmp_path / "run.parquet"
    r = _dyno("export", run_dir, "--format", "parquet", "--out", out)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == str(out)
    back = read_parquet(out)
    _check(back, run_dir)
    assert back["units"]["t_us"] == "us" and back["units"]["adc_code"] == "counts"


def test_mdf4_round_trip(run_dir, tmp_path):
    pytest.importorskip("asammdf", reason="asammdf (the [export] extra) is not installable here")
    from dyno.library.exports import read_mdf4

    out = tmp_path / "run.mf4"
    r = _dyno("export", run_dir, "--format", "mdf4", "--out", out)
    assert r.returncode == 0, r.stderr
    back = read_mdf4(out)
    _check(back, run_dir)
    assert back["units"]["primary_edge_t_us"] == "us" and back["units"]["adc_code"] == "N·m"
    # the conversion on adc_code is the run's calibration: physical values are torque
    cal = load_run(run_dir).calibration
    want = (back["adc_code"].astype(float) - cal["intercept_counts"]) / cal["slope_counts_per_nm"]
    assert np.allclose(back["adc_torque_nm"], want, rtol=1e-12, atol=1e-9)
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_default_out_and_csv_still_default(run_dir):
    pytest.importorskip("pyarrow")
    r = _dyno("export", run_dir, "--format", "parquet")
    assert r.returncode == 0 and Path(r.stdout.strip()) == run_dir / "export" / "run.parquet"
    r = _dyno("export", run_dir)
    assert r.returncode == 0 and (run_dir / "export" / "points.csv").is_file()


@pytest.mark.parametrize("fmt,module", [("parquet", "pyarrow"), ("mdf4", "asammdf")])
def test_missing_extra_is_one_line_exit_2(run_dir, tmp_path, fmt, module):
    # a stand-in module that fails to import, ahead of the real one on the path
    blocker = tmp_path / "blocked"
    blocker.mkdir()
    (blocker / f"{module}.py").write_text("raise ImportError('blocked by the test')\n")
    out = tmp_path / "x.out"
    r = _dyno("export", run_dir, "--format", fmt, "--out", out, pythonpath=[str(blocker)])
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "pip install 'dyno[export]'" in r.stderr and module in r.stderr
    assert "Traceback" not in r.stderr and not out.exists()


def test_bad_format_and_out_is_a_directory(run_dir, tmp_path):
    r = _dyno("export", run_dir, "--format", "xlsx")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    pytest.importorskip("pyarrow")
    r = _dyno("export", run_dir, "--format", "parquet", "--out", tmp_path)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
