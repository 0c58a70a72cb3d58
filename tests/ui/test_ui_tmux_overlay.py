"""The real `dyno ui --sim` in tmux with the belt-model overlay on: predictions on screen, clean exit."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from tests.ui.test_ui_tmux import _go, _tmux, _wait_screen

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")


def test_ui_tmux_overlay_shows_full_model_and_exits_cleanly(tmp_path):
    from dyno.model.overlay import default_cache_dir

    session = f"dyno-ovl-{uuid.uuid4().hex[:8]}"
    run_dir = tmp_path / "run"
    env = {"TERM": "xterm-256color", "PATH": "/usr/bin:/bin", "HOME": str(tmp_path),
           "PYTHONPATH": str(Path(__file__).resolve().parents[2]),
           # the simulated CVT's belt table is in the session's model cache (tests/conftest.py)
           "DYNO_MODEL_CACHE": os.environ.get("DYNO_MODEL_CACHE", str(default_cache_dir()))}
    # in the command itself: a tmux server already running (another test's) would not pass env= on
    prefix = "env " + " ".join(f"{k}={shlex.quote(v)}" for k, v in env.items())
    # the thesis's open-loop steps: its first points are at part load, where the default (first-estimate) tune's
    # clamp carries the belt; the default speed-hold plan's are at full load, where the model finds gross slip
    # at that clamp (8 of 8 in one run: no "full 1/" ever, only "8 fail" -- the physics' answer)
    cmd = (f"{prefix} {sys.executable} -m dyno ui --sim --speed 8 --plan thesis-step --out {run_dir} ; "
           "echo EXITED=$? ; sleep 30")
    subprocess.run(["tmux", "new-session", "-d", "-x", "80", "-y", "24", "-s", session, cmd], check=True,
                   timeout=20, env=env)
    try:
        _wait_screen(session, "ARMED", 60)
        _tmux("send-keys", "-t", session, "o")  # the solver's process starts; a seed is solved
        _wait_screen(session, "no points yet", 10)
        _go(session)
        screen = _wait_screen(session, "full 1/", 120)  # the first point's full-model prediction
        assert "overlay" in screen and "ABORTED" not in screen
        _tmux("send-keys", "-t", session, "C-c")  # E-STOP
        _wait_screen(session, "cause: estop", 10)
        _tmux("send-keys", "-t", session, "q")
        screen = _wait_screen(session, "EXITED=0", 30)  # the worker process does not hold the exit
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True, timeout=20)
