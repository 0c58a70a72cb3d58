"""Headless progress: a live status line on a terminal (state, point n/~N, ETA); nothing when piped
(tests/e2e/test_entry_points.py::test_closed_pipe_keeps_a_runs_exit_code)."""

from __future__ import annotations

import io
import json
import shutil
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from dyno.cli.progress import WIDTH, TtyProgress, status_line
from dyno.control.progress import estimate

REPO = Path(__file__).resolve().parents[2]


def test_estimate():
    assert estimate([5000.0], [1.0], 1500, 20) == (None, None)  # one point says nothing about the pace
    # early: mostly the plan's 20 points, 10 s per point
    total, eta = estimate([5000.0, 4800.0], [0.0, 10.0], 1500, 20)
    assert total == 20 and eta == pytest.approx(10.0 * (7 / 8 * 18 + 1 / 8 * 16.5))
    # later: the speed still to shed at the recent drop per point (100 rpm, 5 s each)
    rpm = [3000.0 - 100.0 * k for k in range(10)]
    total, eta = estimate(rpm, [5.0 * k for k in range(10)], 1500, 20)
    assert total == 10 + 6 and eta == pytest.approx(30.0)
    assert estimate([2000.0, 1400.0], [0.0, 5.0], 1500, 2) == (2, 0.0)  # past the stop speed: done


def test_status_line_fits_80_columns():
    line = status_line("measure", 17, 120, 3234.4, 1649.2, 3725.0, 4000.0)
    assert len(line) <= WIDTH and line.startswith("MEASURE") and "point 17/~120" in line
    assert line.endswith("engine/secondary 3234/1649 rpm") and "ETA 66:40" in line and "ran 62:05" in line
    assert "ETA —" in status_line("warmup", 0, None, 3800, 0, 2, None)


def test_progress_draws_at_most_once_per_period_and_erases_itself():
    t = [0.0]
    out = io.StringIO()
    bar = TtyProgress(out, wall_clock=lambda: t[0], period_s=0.25)
    poller = SimpleNamespace(listeners=[], rpm=lambda ch: 3000.0)
    plan = SimpleNamespace(min_secondary_rpm=1500.0, target_points=20)
    ctrl = SimpleNamespace(points=[], plan=plan, state=SimpleNamespace(value="settle"))
    bar.attach(SimpleNamespace(poller=poller, controller=ctrl))
    for k in range(100):  # 100 polls over 1 s of wall time
        t[0] = k * 0.01
        poller.listeners[0]([], k)
    assert bar.drawn == 4
    ctrl.points += [{"rpm_secondary": 5000.0}, {"rpm_secondary": 4000.0}]
    t[0] = 2.0
    poller.listeners[0]([], 200)
    assert "point 2" in out.getvalue().split("\r")[-1]
    bar.finish()
    assert out.getvalue().endswith("\r\x1b[K")


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_progress_on_a_terminal(tmp_path, terminal):
    run_dir = tmp_path / "run"
    cmd = f"{sys.executable} -m dyno run --sim --headless --out {run_dir} ; echo EXITED=$? ; sleep 30"
    session = terminal(cmd, size=(80, 30), env={"HOME": str(tmp_path), "PYTHONPATH": str(REPO)})
    seen, screen = set(), ""
    try:
        t_end = time.monotonic() + 120
        while time.monotonic() < t_end and "EXITED=" not in screen:
            screen = session.screen()
            for line in screen.splitlines():
                if line.startswith(("WARMUP", "STEP", "SETTLE", "MEASURE")) and "ETA" in line:
                    seen.add(line.split()[0])
                    if "/~" in line and "ETA —" not in line:
                        seen.add("eta")
            time.sleep(0.1)
    finally:
        session.close()
    assert "EXITED=0" in screen, screen
    assert {"MEASURE", "eta"} <= seen, seen
    assert "ETA" not in screen and "report: " in screen  # the line was erased before the results
    stop = [json.loads(ln) for ln in (run_dir / "documents.jsonl").read_text().splitlines() if '"stop"' in ln]
    assert stop[-1]["exit_status"] == "success"
