"""The soak, short: ~30 simulated minutes of back-to-back runs of every shipped plan in one process.

``bench/bench_soak.py`` as a real process (1 % mixed transfer faults, a random drill every 5 simulated
minutes, re-armed after each): no unhandled exception, no point lost, every run indexed and replayable,
the pads off the rotor after every abort, file descriptors flat.  The 8-hour figures are in docs/safety.md.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_half_an_hour_soak_keeps_every_run(tmp_path):
    runs = tmp_path / "runs"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    p = subprocess.run([sys.executable, str(REPO / "bench" / "bench_soak.py"), "--hours", "0.5", "--report-min", "10",
                        "--drill-every-min", "5", "--seed", "3", "--runs-dir", str(runs), "--json"],
                       cwd=tmp_path, env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=1500)
    assert "Traceback" not in p.stderr, p.stderr[-3000:]
    out = json.loads(p.stdout)
    tail = p.stderr[-3000:]
    assert out["sim_s"] >= 0.5 * 3600 and out["runs"] >= 8, out  # it did soak: every plan at least once
    assert out["drills_fired"] >= 3 and sum(out["aborts"].values()) >= 1, out  # aborts to check the brake on
    assert out["exceptions"] == 0, out["exception_texts"]
    assert out["checks"]["no_points_lost"], (out["rows"][-1], tail)
    assert out["checks"]["every_run_indexed"] and out["checks"]["every_run_replayable"], (out["rows"][-1], tail)
    assert out["checks"]["pads_off_after_every_abort"], (out["findings"], tail)
    fds = [r["fds"] for r in out["rows"]]
    assert max(fds) - min(fds) <= 1, fds
    last = out["rows"][-1]
    run_dirs = sorted(d for d in runs.iterdir() if (d / "meta.json").is_file())
    assert last["run_dirs"] == last["library_entries"] == len(run_dirs) == out["runs"], (last, len(run_dirs))
    assert p.returncode == 0, tail
