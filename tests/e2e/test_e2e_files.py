"""Run logs survive SIGKILL; malformed inputs are refused with one line, exit 2, nothing changed."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dyno.runlog.replay import replay
from dyno.runlog.reader import load_run

REPO = Path(__file__).resolve().parents[2]


def _dyno(*args, **kw):
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          cwd=kw.pop("cwd", REPO), timeout=kw.pop("timeout", 120), **kw)


def test_sigkilled_run_replays_every_completed_point(tmp_path):
    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--speed", "60",
                             "--out", str(out)], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    docs = out / "documents.jsonl"
    deadline = time.monotonic() + 90
    try:
        while time.monotonic() < deadline:
            if docs.exists() and docs.read_text().count('"type": "point"') >= 3:
                break
            if proc.poll() is not None:
                pytest.fail(f"run ended before it could be killed: {proc.stderr.read()}")
            time.sleep(0.05)
        else:
            pytest.fail("no 3 points within 90 s")
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    run = load_run(out)
    assert run.stop is None  # it really was killed mid-run
    logged = run.points
    assert len(logged) >= 3
    again = replay(out)
    assert [p["index"] for p in again["points"]] == [p["index"] for p in logged]
    for live, re in zip(logged, again["points"]):
        assert re["efficiency"] == pytest.approx(live["efficiency"], rel=1e-12)
    # the replay CLI works on the killed run too
    res = _dyno("replay", out, "--json")
    assert res.returncode == 0, res.stderr
    assert len(json.loads(res.stdout)["points"]) == len(logged)


def test_torn_tail_is_ignored(tmp_path):
    """A kill can tear the last record: readers drop it and keep everything before."""
    out = tmp_path / "torn"
    res = _dyno("run", "--sim", "--headless", "--out", out, "--seed", "4")
    assert res.returncode == 0, res.stderr
    before = load_run(out)
    with open(out / "documents.jsonl", "a") as f:
        f.write('{"type": "point", "index": 99, "t_sta')
    with open(out / "events.bin", "ab") as f:
        f.write(b"\x01\x02\x03")
    after = load_run(out)
    assert len(after.points) == len(before.points)
    assert after.torn == {"documents": '{"type": "point", "index": 99, "t_sta', "events_bytes": 3}
    assert after.streams.counts() == before.streams.counts()


BAD_CAL = "date,slope_counts_per_nm,intercept_counts,r2,n_samples,lever_arm_m,gear_ratio_brake_per_secondary,note\n" \
          "2024-01-01,abc,35145,0.9997,500,0.15,0.5246,x\n"
BAD_MAP = "rpm,torque_nm\n2000,18\n1500,17\n"
BAD_RIG_EDIT = ("firmware_address = 0x03", "firmware_address = 0x93")


@pytest.mark.parametrize("kind", ["calibration", "engine-map", "rig"])
def test_malformed_inputs_exit_2_with_one_line_and_change_nothing(tmp_path, kind):
    if kind == "calibration":
        bad = tmp_path / "cal.csv"
        bad.write_text(BAD_CAL)
        field = "slope_counts_per_nm"
    elif kind == "engine-map":
        bad = tmp_path / "map.csv"
        bad.write_text(BAD_MAP)
        field = "rpm"
    else:
        bad = tmp_path / "rig.toml"
        bad.write_text((REPO / "hardware" / "rig.toml").read_text().replace(*BAD_RIG_EDIT))
        field = "firmware_address"
    content = bad.read_bytes()
    out = tmp_path / "run"
    res = _dyno("run", "--sim", "--headless", f"--{kind}", bad, "--out", out)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert str(bad) in lines[0] and field in lines[0]
    assert not out.exists()  # nothing created
    assert bad.read_bytes() == content  # nothing changed
