"""The safety benches run to the end as real processes (their --quick smoke runs) and every row they print
meets its bounds as the physics sees them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _bench(*args, timeout=900):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True, cwd=REPO, env=env,
                          timeout=timeout)


def test_bench_safety_quick_every_plan_ends_physically_safe():
    p = _bench(REPO / "bench" / "bench_safety.py", "--quick", "--workers", "2", "--json")
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    rows = json.loads(p.stdout)
    plans = {r["plan"] for r in rows}
    assert plans == {"speed-hold", "thesis-step", "torque-hold", "engine-hold", "sweep", "engagement",
                     "coast-down", "drive-grid"}
    assert any(r["mode"] == "mock" for r in rows)
    for r in rows:
        assert r["bad"] == [] and r["physics_safe"] and r["rig_safe"] and r["listed"], r
        assert r["release_s"] <= r["release_bound_s"], r
    # the brake was working when the fault came on the plans that load it: a real release was measured
    assert sum(1 for r in rows if (r["brake_mm_at_safe"] or 0) > 1.0) >= 5, rows
    assert "runs, 0 out of bound" in p.stderr


def test_bench_safety_quick_one_drill_as_a_process():
    p = _bench(REPO / "bench" / "bench_safety.py", "--timed", "--quick", "--only", "bus-lost", "--json")
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    rows = json.loads(p.stdout)
    assert rows and all(r["ok"] and r["physics_safe"] for r in rows), rows


def test_bench_safety_the_loop_liveness_drills_as_a_process():
    """Issue 49's drills in the timed bench: loop-freeze through the real-rig output code, loop-stall:300 past the
    liveness limit (cut by the Nano), both within their bounds; loop-stall:200 survived."""
    for only, mock in (("loop-freeze", ["--mock-pins"]), ("loop-stall:", [])):
        p = _bench(REPO / "bench" / "bench_safety.py", "--timed", "--quick", "--only", only, "--json", *mock)
        assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
        rows = {r["drill"]: r for r in json.loads(p.stdout)}
        assert all(r["ok"] and r["physics_safe"] for r in rows.values()), rows
        if only == "loop-freeze":
            assert rows["loop-freeze"]["state"] == "aborted" and rows["loop-freeze"]["latency_s"] <= 0.3
        else:
            assert rows["loop-stall:200"]["state"] == "done"
            assert rows["loop-stall:300"]["cause"] == "nano_heartbeat"
