"""`dyno ui` and `dyno calibrate` without --sim on a machine with no GPIO / I2C (this one): one line naming what
is missing, exit 2, no traceback — as real processes, like `dyno doctor`."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

REPO = Path(__file__).resolve().parents[2]


def _on_a_pi() -> bool:
    return Path("/proc/device-tree/model").exists() or Path("/dev/gpiochip0").exists()


@pytest.mark.skipif(_on_a_pi(), reason="this machine has GPIO: the rig entry points would really start")
@pytest.mark.parametrize("command", ["ui", "calibrate"])
def test_rig_entry_point_without_hardware_is_one_line_exit_2(command, tmp_path):
    rig = str(REPO / "hardware" / "rig.toml")  # a rig file of its own (the shipped one is refused on hardware)
    p = subprocess.run([sys.executable, "-m", "dyno", command, "--rig", rig], capture_output=True, text=True,
                       timeout=60, cwd=tmp_path, stdin=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert p.returncode == 2, p.stderr[-2000:]
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr[-2000:]
    assert lines[0].startswith(f"dyno {command}: error:") and ("GPIO" in lines[0] or "i2c" in lines[0]), lines
    assert not list(tmp_path.iterdir()), "nothing may be written"
