"""Runs side by side: six `dyno run` processes started together without --out each get their own run
directory, all exit 0, and every one is in the run library's index (issue 23).

The index is read straight from its SQLite file, not through `dyno runs` (which re-syncs from the directories
and would hide an entry the end-of-run hook lost).
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

from dyno.library.index import INDEX_NAME

REPO = Path(__file__).resolve().parents[2]
N_RUNS = 6
PLAN = "coast-down"  # the quickest shipped plan that ends "done" (~6 s alone, ~20 s six at once on 2 cores)


def test_six_runs_started_together_get_six_directories_all_indexed(tmp_path):
    root = tmp_path / "runs"
    env = dict(os.environ, DYNO_RUNS_DIR=str(root), PYTHONPATH=str(REPO))
    t0 = time.monotonic()
    procs = [subprocess.Popen([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--json", "--plan", PLAN,
                               "--seed", str(seed)], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
             for seed in range(1, N_RUNS + 1)]
    outs = [p.communicate(timeout=300) for p in procs]
    wall_s = time.monotonic() - t0
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0 and "Traceback" not in err, f"exit {p.returncode}\n{err[-3000:]}"
        assert "not indexed" not in err, err  # the end-of-run hook's one line when indexing failed
    docs = [json.loads(out) for out, _ in outs]
    assert all(d["state"] == "done" for d in docs)

    run_dirs = {str(Path(d["run_dir"]).resolve()) for d in docs}
    assert len(run_dirs) == N_RUNS  # nobody shared (or overwrote) another's directory
    on_disk = {str(p.resolve()) for p in root.iterdir() if (p / "meta.json").is_file()}
    assert on_disk == run_dirs

    conn = sqlite3.connect(root / INDEX_NAME)
    try:
        indexed = {r[0] for r in conn.execute("SELECT path FROM runs")}
        states = {r[0] for r in conn.execute("SELECT state FROM runs")}
    finally:
        conn.close()
    assert indexed == run_dirs  # every run's own hook indexed it, none lost to another's write
    assert states == {"done"}
    print(f"{N_RUNS} runs side by side: {wall_s:.1f} s")
