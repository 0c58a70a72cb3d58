"""An entry point whose terminal goes (the tmux pane closed, an SSH session lost) ends, safe state first:
started from a shell, left at its first screen, gone soon after the pane closes."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from tests.screens import wait_screen

REPO = Path(__file__).resolve().parents[2]


def _pids(marker: str) -> list[int]:
    p = subprocess.run(["pgrep", "-f", marker], capture_output=True, text=True)
    return [int(x) for x in p.stdout.split()]


@pytest.mark.skipif(shutil.which("tmux") is None or shutil.which("pgrep") is None, reason="needs tmux and pgrep")
@pytest.mark.parametrize("command, screen", [
    (["calibrate", "--sim"], "Enter the rope radius"),
    (["ui", "--sim"], "E-STOP"),
])
def test_entry_point_ends_when_its_terminal_goes(command, screen, tmp_path):
    seed = str(40_000 + uuid.uuid4().int % 10_000)  # marks this process for pgrep
    name = f"dyno-hup-{uuid.uuid4().hex[:8]}"
    args = " ".join([sys.executable, "-m", "dyno", *command, "--seed", seed])
    subprocess.run(["tmux", "new-session", "-d", "-x", "100", "-y", "30", "-s", name, "-c", str(tmp_path), "bash",
                    "--norc"], check=True, timeout=20)
    try:
        subprocess.run(["tmux", "send-keys", "-t", name, f"PYTHONPATH={REPO} {args}; echo done", "Enter"],
                       timeout=20)
        wait_screen(name, screen, 90)
        marker = f"dyno {' '.join(command)} --seed {seed}"
        assert _pids(marker), "not running"
    finally:
        subprocess.run(["tmux", "kill-session", "-t", name], capture_output=True, timeout=20)
    t0 = time.monotonic()
    while _pids(marker) and time.monotonic() - t0 < 10:
        time.sleep(0.05)
    left = _pids(marker)
    for pid in left:  # do not leave it behind for the next test
        subprocess.run(["kill", "-9", str(pid)])
    assert not left, f"still running {time.monotonic() - t0:.1f} s after its terminal closed"
    assert time.monotonic() - t0 <= 3.0  # (2.0 s seen on a machine running two test workers and a bench)
