"""Bad input, fed to each command as a real process: one line naming the file/field and what is
expected, exit 2, no traceback, nothing written or changed."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.bad_input import one_line_failures, snapshot

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _dyno(*args, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          timeout=120, env=ENV, cwd=cwd)


@pytest.fixture(scope="module")
def good_run(tmp_path_factory):
    """A small real run directory (aborted early by a drill: cheap), to be corrupted in copies."""
    root = tmp_path_factory.mktemp("good")
    r = _dyno("run", "--sim", "--headless", "--json", "--out", root / "run", "--drill", "overspeed@4", cwd=root)
    assert r.returncode == 3, r.stderr
    return root / "run"


def _rig_with(tmp: Path, old: str, new: str) -> Path:
    text = (REPO / "hardware" / "rig.toml").read_text()
    assert old in text
    p = tmp / "rig.toml"
    p.write_text(text.replace(old, new, 1))
    return p


def _cases(tmp: Path, run: Path):
    """(name, argv, what the one line must name)."""
    bad_bytes = tmp / "binary.csv"
    bad_bytes.write_bytes(b"\xff\xfe\x00garbage\x80\x81\n")
    cal = tmp / "cal.csv"
    cal.write_text("date,slope_counts_per_nm,intercept_counts\n2024-01-01,abc,3\n")
    emap = tmp / "map.csv"
    emap.write_text("rpm,throttle,torque_nm\n1000,1.0,nan\n")
    tune = tmp / "tune.toml"
    tune.write_text("[drive]\nsheave_half_angle_deg = 200\n")
    huge = tmp / "huge.csv"
    huge.write_text("date,slope_counts_per_nm,intercept_counts,r2,n_samples,lever_arm_m,gear_ratio_brake_per_secondary,"
                    "note\n2024-01-01,1e308,1e308,1.0,0,,1e308,x\n")
    a_dir = tmp / "a_dir"
    a_dir.mkdir()
    # run directories broken in different ways (copies of a real one)
    no_meta = tmp / "no_meta"
    shutil.copytree(run, no_meta)
    (no_meta / "meta.json").unlink()
    bad_meta = tmp / "bad_meta"
    shutil.copytree(run, bad_meta)
    (bad_meta / "meta.json").write_text("{not json")
    bin_docs = tmp / "bin_docs"
    shutil.copytree(run, bin_docs)
    (bin_docs / "documents.jsonl").write_bytes(b"\xff\xfe{\n\x80\n" + (run / "documents.jsonl").read_bytes())
    meta_list = tmp / "meta_list"
    shutil.copytree(run, meta_list)
    (meta_list / "meta.json").write_text("[1, 2, 3]")
    out = tmp / "never"
    sim = ("run", "--sim", "--headless", "--out", out)
    return [
        ("rig inf limit", [*sim, "--rig", _rig_with(tmp / "r1", "rotor_temp_max_c = 250.0", "rotor_temp_max_c = inf")],
         "limits.rotor_temp_max_c"),
        ("rig inf poll", [*sim, "--rig", _rig_with(tmp / "r2", "poll_hz = 150", "poll_hz = inf")], "poll_hz"),
        ("fault rate 2", [*sim, "--fault-rate", "2"], "--fault-rate"),
        ("speed nan", [*sim, "--speed", "nan"], "--speed"),
        ("speed 0", [*sim, "--speed", "0"], "--speed"),
        ("calibration field", [*sim, "--calibration", cal], "cal.csv"),
        ("calibration binary", [*sim, "--calibration", bad_bytes], "binary.csv"),
        ("calibration huge", [*sim, "--calibration", huge], "huge.csv"),
        ("calibration is a dir", [*sim, "--calibration", a_dir], "a_dir"),
        ("engine map nan", [*sim, "--engine-map", emap], "map.csv"),
        ("engine map binary", [*sim, "--engine-map", bad_bytes], "binary.csv"),
        ("tune range", [*sim, "--tune", tune], "tune.toml"),
        ("replay no meta", ["replay", no_meta, "--json"], "meta.json"),
        ("replay bad meta", ["replay", bad_meta, "--json"], "meta.json"),
        ("replay meta list", ["replay", meta_list, "--json"], "meta.json"),
        ("replay binary docs", ["replay", bin_docs, "--json"], "documents.jsonl"),
        ("replay missing dir", ["replay", tmp / "nowhere", "--json"], "nowhere"),
        ("replay viewer missing dir", ["replay", tmp / "nowhere"], "nowhere"),
        ("replay viewer bad meta", ["replay", bad_meta], "meta.json"),
        ("replay bad calibration", ["replay", run, "--json", "--calibration", cal], "cal.csv"),
        ("export bad meta", ["export", bad_meta], "meta.json"),
        ("import-legacy binary", ["import-legacy", a_dir], "a_dir"),
        ("calibrate radius", ["calibrate", "--sim", "--radius", "-1"], "--radius"),
        ("calibrate bad rig", ["calibrate", "--sim", "--rig", _rig_with(tmp / "r3", "poll_hz = 150", "poll_hz = 0")],
         "poll_hz"),
        ("ui bad rig", ["ui", "--sim", "--rig", _rig_with(tmp / "r4", "watchdog_s = 0.5", "watchdog_s = nan")],
         "actuator.watchdog_s"),
        ("doctor bad rig", ["doctor", "--sim", "--rig", _rig_with(tmp / "r5", "comms_timeout_s = 0.25",
                                                                  "comms_timeout_s = -1")], "limits.comms_timeout_s"),
        ("drill unknown", [*sim, "--drill", "nope@1"], "--drill"),
    ]


def test_every_bad_input_is_one_line_exit_2_and_nothing_changes(tmp_path, good_run):
    for d in ("r1", "r2", "r3", "r4", "r5"):
        (tmp_path / d).mkdir()
    cases = _cases(tmp_path, good_run)
    before = snapshot(tmp_path)
    failures = one_line_failures(cases, lambda *argv: _dyno(*argv, cwd=tmp_path))
    assert not failures, "\n".join(failures)
    assert snapshot(tmp_path) == before  # nothing written, nothing changed
    assert not (tmp_path / "never").exists() and not (tmp_path / "runs").exists()


def test_second_process_on_the_same_out_refuses_and_the_first_is_unharmed(tmp_path):
    out = tmp_path / "run"
    first = subprocess.Popen([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--json", "--speed", "2",
                              "--out", str(out), "--drill", "overspeed@4"], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=ENV, cwd=tmp_path)
    try:
        import time

        t_end = time.monotonic() + 60
        while not (out / "meta.json").exists() and time.monotonic() < t_end:
            time.sleep(0.05)
        assert (out / "meta.json").exists()
        second = _dyno("run", "--sim", "--headless", "--out", out, cwd=tmp_path)
        assert second.returncode == 2
        err = second.stderr.strip()
        assert len(err.splitlines()) == 1 and "--out" in err and "Traceback" not in err, err
        stdout, stderr = first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 3, stderr  # aborted by its drill, as planned: not by the second process
    rep = _dyno("replay", out, "--json", cwd=tmp_path)
    assert rep.returncode == 0, rep.stderr
    # what a run leaves behind: files 0644, directories 0755 (readable by the team), no lock
    assert not (out / ".dyno-lock").exists()
    assert oct(out.stat().st_mode & 0o777) == "0o755"
    for p in out.iterdir():
        assert oct(p.stat().st_mode & 0o777) == "0o644", p


def test_a_speed_the_machine_cannot_reach_is_said_in_one_line(tmp_path):
    r = _dyno("run", "--sim", "--headless", "--speed", "1000", "--drill", "overspeed@4", "--out", tmp_path / "run",
              cwd=tmp_path)
    assert r.returncode == 3  # the drill's abort: the pace changes nothing else
    lines = [ln for ln in r.stderr.splitlines() if "not reached" in ln]
    assert len(lines) == 1 and "--speed 1000" in lines[0] and "Traceback" not in r.stderr


@pytest.mark.parametrize("argv", [
    ["run", "--sim", "--headless", "--json", "--tune", "no-such-tune.toml"],  # refused by the command
    ["run", "--sim", "--headless", "--json", "--speed", "fast"],  # refused by the argument parser
    ["tune", "advise", "no-such-run", "--target", "engagement=2100", "--json"],
])
def test_with_json_a_refusal_is_a_json_document_too(tmp_path, argv):
    """--json promises one JSON document on every way out: a script reading stdout must not get nothing."""
    import json

    r = _dyno(*argv, cwd=tmp_path)
    line = r.stderr.strip()
    assert r.returncode == 2 and len(line.splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    assert json.loads(r.stdout) == {"error": line, "exit_code": 2}
    assert list(tmp_path.iterdir()) == []  # nothing written
