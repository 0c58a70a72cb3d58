"""Building the firmware's simavr ELF from a test (under the lock tests/firmware builds under, so pytest-xdist
workers never run make on the same tree at once): a test that needs the ELF builds it, whatever ran first."""

from __future__ import annotations

import fcntl
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ELF = REPO / "firmware" / "build" / "dyno_nano.elf"


def make(*targets: str, timeout_s: float | None = None) -> subprocess.CompletedProcess:
    """``make -s -C firmware TARGETS`` under the build lock."""
    (REPO / "firmware" / "build").mkdir(exist_ok=True)
    with open(REPO / "firmware" / "build" / ".make.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return subprocess.run(["make", "-s", "-C", str(REPO / "firmware"), *targets], capture_output=True,
                              text=True, timeout=timeout_s)


def sim_elf() -> Path:
    """The ``make -C firmware sim`` ELF, built if needed; skips (naming what is missing) without the toolchain."""
    from dyno.transports.simavr import toolchain_missing

    why = toolchain_missing()
    if why:
        pytest.skip(f"AVR toolchain/simavr not installed: {why}")
    build = make("sim", timeout_s=600.0)
    assert build.returncode == 0, build.stdout + build.stderr
    return ELF
