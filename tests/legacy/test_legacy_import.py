"""dyno import-legacy on the thesis rig's real logs (read in place) and on synthetic folders."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from dyno.session.summary import public_point
from dyno.cli import main
from dyno.datapaths import legacy_data_dir, legacy_data_missing
from dyno.errors import ConfigError
from dyno.runlog.replay import replay
from dyno.runlog.legacy import import_legacy
from dyno.runlog.reader import load_run

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

DATA = legacy_data_dir()
RUNS = ("2019-04-18_run2", "2019-04-18_run3", "2019-04-18_run4")
needs_data = pytest.mark.skipif(legacy_data_missing() is not None, reason=str(legacy_data_missing()))


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    if legacy_data_missing():
        pytest.skip(legacy_data_missing())
    root = tmp_path_factory.mktemp("legacy")
    return {name: import_legacy(DATA / name, root / name) for name in RUNS}


def _public(p):
    # JSON round trip: NaN -> None via public_point, numpy scalars -> float
    return json.loads(json.dumps(public_point(p), default=float))


@needs_data
@pytest.mark.parametrize("name", RUNS)
def test_legacy_replay_equals_import(imported, name):
    res = imported[name]
    run = load_run(res["run_dir"])
    again = replay(res["run_dir"])["points"]
    assert len(run.points) == len(again) == len(res["points"]) > 20
    for doc, rp in zip(run.points, again):
        # including the points the importer withheld: replay keeps them withheld
        assert _public(doc) == _public(rp), doc["legacy_point"]
    withheld = [d["legacy_point"] for d in run.points if d.get("withheld_by_import")]
    assert withheld == ([15] if name.endswith("run2") else [])


@needs_data
@pytest.mark.parametrize("name", RUNS[:2])
def test_legacy_efficiency_plausible_and_torque_matches_thesis(imported, name):
    res = imported[name]
    valid = [p for p in res["points"] if p["legacy_point"] in res["summary"]["valid_points"]]
    assert len(valid) >= 25
    for p in valid:
        assert 0 < p["efficiency"] < 1, p["legacy_point"]
        # The thesis's own converted torque, de-duplicated like the ADC rows (one value per new timestamp).
        rows = np.loadtxt(DATA / name / f"TORQUE_{p['legacy_point']}.csv", delimiter=",", ndmin=2)
        t, v, kept = rows[:, 0], rows[:, 1], []
        for i in range(len(t)):
            if not kept or t[i] > t[kept[-1]]:
                kept.append(i)
        thesis_nm = v[kept].mean()
        assert p["torque_secondary_nm"] == pytest.approx(thesis_nm, rel=0.01), p["legacy_point"]


@needs_data
def test_legacy_point0_discarded(imported):
    for res in imported.values():
        p0 = res["points"][0]
        assert p0["legacy_point"] == 0 and p0["discarded"] is True
        assert 0 not in res["summary"]["valid_points"]


@needs_data
def test_legacy_run4_dead_adc_is_a_fault_on_every_point(imported):
    res = imported["2019-04-18_run4"]
    assert res["summary"]["n_valid"] == 0
    for p in res["points"]:
        assert math.isnan(p["efficiency"]) and not p["valid"]
        dead = [f for f in res["faults"] if f["point"] == p["legacy_point"] and f["channel"] == "adc"
                and f["severity"] == "error" and "never changes" in f["reason"]]
        assert len(dead) == 1, p["legacy_point"]
    # the bogged-down last point is flagged unsteady
    assert any(f["point"] == 25 and "not steady" in f["reason"] for f in res["faults"])


@needs_data
def test_legacy_known_faults_of_run2_and_run3(imported):
    def has(name, point, channel, text, severity=None):
        return any(f["point"] == point and f["channel"] == channel and text in f["reason"]
                   and (severity is None or f["severity"] == severity) for f in imported[name]["faults"])

    assert has("2019-04-18_run2", 17, "all", "stalled")
    assert has("2019-04-18_run2", 15, "adc", "glitch", "error")
    assert has("2019-04-18_run2", 3, "adc", "going back")
    assert has("2019-04-18_run3", 14, "all", "short point")
    assert has("2019-04-18_run3", 1, "secondary", "missed edges")
    for res in imported.values():
        for f in res["faults"]:
            assert {"point", "channel", "reason", "severity"} <= f.keys()


@needs_data
def test_legacy_cli_json_and_refuses_overwrite(tmp_path, capsys):
    out = tmp_path / "run3"
    assert main(["import-legacy", str(DATA / RUNS[1]), "--out", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["run_dir"] == str(out) and len(doc["points"]) == 29
    assert all(p["efficiency"] is None or 0 < p["efficiency"] < 1 for p in doc["points"])
    assert main(["replay", str(out), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    strip = [{k: v for k, v in p.items() if k not in ("legacy_point", "discarded")} for p in doc["points"]]
    assert strip == again["points"]
    before = sorted(out.iterdir())
    assert main(["import-legacy", str(DATA / RUNS[1]), "--out", str(out)]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert sorted(out.iterdir()) == before


# ---------------------------------------------------------------------------
# synthetic folders (no real data needed)

CAL = "108.188097293,35144.7019735,0.999727300946\n"
MAP = "1500,3.0\n2500,6.0\n3500,7.6\n3800,2.0\n"


def _write_point(folder: Path, n: int, t0_us: int, *, adc=None, rpm_p=3000, rpm_s=2500, seconds=3.0):
    """One point as the thesis software wrote it: 150 Hz polls of the latest edge / conversion."""
    rng = np.random.default_rng(n)
    polls = t0_us + np.arange(int(seconds * 150)) * 6667
    wrap = 1 << 32

    def sampled(period_us, jitter, first_us):
        # event times with some period jitter (real Hall rpm is never constant), then what each poll saw
        periods = np.rint(period_us * (1 + jitter * rng.standard_normal(int(seconds * 1e6 / period_us) + 4)))
        t = first_us + np.concatenate([[0], np.cumsum(periods)[:-1]]).astype(np.int64)
        idx = np.maximum(np.searchsorted(t, polls, side="right") - 1, 0)
        return t, idx, np.concatenate([[periods[0]], periods[:-1]])

    rows = {}
    for name, rpm in (("P", rpm_p), ("S", rpm_s)):
        t, idx, periods = sampled(60e6 / rpm, 0.01, t0_us - 100)
        rows[name] = (t[idx], np.rint(60e6 / periods[idx]).astype(int))
    t, idx, _ = sampled(7876, 0.0, t0_us - 50)
    if adc is None:  # ~20 N·m with noise, one value per conversion
        codes = (35144.7 + 108.188 * 20 + rng.normal(0, 50, t.size)).astype(int)
    else:
        codes = np.full(t.size, adc)
    rows["ADC"] = (t[idx], codes[idx])
    rows["TORQUE"] = (t[idx], (codes[idx] - 35144.7019735) / 108.188097293)
    for name, (ts, vs) in rows.items():
        (folder / f"{name}_{n}.csv").write_text("".join(f"{int(ti) % wrap},{vi}\n" for ti, vi in zip(ts, vs)))


def _folder(tmp_path: Path, t0_us: int = 10_000_000, adc_stuck=None) -> Path:
    top = tmp_path / "legacy"
    run = top / "run"
    run.mkdir(parents=True)
    (top / "cal_values.csv").write_text(CAL)
    (top / "engine_power_RPM.csv").write_text(MAP)
    for n in range(3):
        _write_point(run, n, t0_us + n * 7_000_000, adc=adc_stuck if n == 2 else None)
    return run


def test_legacy_synthetic_wrap_and_stuck_adc(tmp_path):
    # Start 8.5 s before the u32 microsecond counter wraps, so it wraps in the middle of point 1.
    run = _folder(tmp_path, t0_us=(1 << 32) - 8_500_000, adc_stuck=36000)
    res = import_legacy(run, tmp_path / "out")
    s = load_run(res["run_dir"]).streams
    assert np.all(np.diff(np.frombuffer(s.edges[1], dtype=np.int64)) > 0)
    p1, p2 = res["points"][1], res["points"][2]
    # point 1 crosses the wrap mid-point, point 2 lies wholly after it
    assert p1["t_start_us"] < (1 << 32) < p1["t_end_us"] < p2["t_start_us"]
    assert p1["rpm_primary"] == pytest.approx(3000, rel=1e-3) and p1["duration_s"] == pytest.approx(3, abs=0.05)
    assert 0 < p1["efficiency"] < 1 and p1["valid"]
    # A non-rail ADC that never changes: reduce_point would average it; the importer withholds it.
    assert math.isnan(p2["efficiency"]) and not p2["valid"]
    assert any("never changes" in f["reason"] for f in p2["faults"])


@pytest.mark.parametrize("bad", ["12345,abc\n", "12345\n", "1,2,3\n", "99999999999,3000\n", "12345,70000\n"])
def test_legacy_malformed_csv_exit_2_one_line_nothing_written(tmp_path, capsys, bad):
    run = _folder(tmp_path)
    target = run / "S_1.csv"
    target.write_text(target.read_text() + bad)
    out = tmp_path / "out"
    assert main(["import-legacy", str(run), "--out", str(out), "--json"]) == 2
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert len(err.splitlines()) == 1 and str(target) in err, err
    # --json: the refusal is a document on stdout too (the same line)
    assert json.loads(cap.out) == {"error": err, "exit_code": 2} and not out.exists()
    with pytest.raises(ConfigError):
        import_legacy(run, out)
    assert not out.exists()


def test_legacy_missing_calibration_is_a_config_error(tmp_path):
    run = _folder(tmp_path)
    (run.parent / "cal_values.csv").unlink()
    with pytest.raises(ConfigError, match="cal_values.csv"):
        import_legacy(run, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_legacy_data_dir_from_env(monkeypatch, tmp_path):
    from dyno import datapaths

    monkeypatch.setenv("DYNO_LEGACY_DATA", str(tmp_path / "absent"))
    assert datapaths.legacy_data_dir() == tmp_path / "absent"
    assert "DYNO_LEGACY_DATA" in datapaths.legacy_data_missing() and "absent" in datapaths.legacy_data_missing()
    monkeypatch.setenv("DYNO_LEGACY_DATA", str(tmp_path))
    assert datapaths.legacy_data_missing() is None
    monkeypatch.delenv("DYNO_LEGACY_DATA")
    assert datapaths.legacy_data_dir() == datapaths.REPO.parent / "shared/data/vt-cvt-dyno-2019"
