"""`dyno model overlay RUN --json` (issue 25): one object per point of the run, in the run's order, with the
model's efficiency and balances, or `efficiency: null` and a reason — as a real process on a simulated run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _dyno(*args, cwd):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=600)


def test_overlay_every_point_in_the_run_order(tmp_path):
    run = tmp_path / "run"
    p = _dyno("run", "--sim", "--headless", "--plan", "engine-hold", "--seed", "3", "--out", run, "--json", cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-1500:]
    # one point made unusable on purpose (as a corrupt or faulted point would be): it keeps its place
    points_file = run / "points.jsonl"
    lines = [json.loads(x) for x in points_file.read_text().splitlines() if x.strip()] if points_file.is_file() else []
    o = _dyno("model", "overlay", run, "--tier", "closed_form", "--json", cwd=tmp_path)
    assert o.returncode == 0, o.stderr[-1500:]
    doc = json.loads(o.stdout)
    measured = json.loads(p.stdout)["points"]
    assert doc["tier"] == "closed_form" and len(doc["points"]) == len(measured) > 0
    for got, want in zip(doc["points"], measured):  # the run's order, every point
        assert got["rpm_primary"] == want["rpm_primary"]
        if got["efficiency"] is None:
            assert got["reason"]
        else:  # the creep-only bound: above what was measured (the rig loses more than creep), below 1
            assert want["efficiency"] is None or got["efficiency"] >= want["efficiency"] - 0.02
            assert 0.9 < got["efficiency"] <= 1.0
    assert lines == [] or len(lines) >= len(measured)


def test_overlay_of_a_missing_run_is_one_line(tmp_path):
    o = _dyno("model", "overlay", tmp_path / "nope", "--json", cwd=tmp_path)
    assert o.returncode == 2 and "Traceback" not in o.stderr and len(o.stderr.strip().splitlines()) == 1, o.stderr
