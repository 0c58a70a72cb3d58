"""`dyno model study --scheduler ADDRESS` on a real dask.distributed cluster (a LocalCluster of two worker
processes on this machine, as a lab's machines would be): the same rows as in one process.

Marked ``cluster``: CI runs it on its own after the main suite (not beside pytest-xdist's workers on the
two cores): README's test command."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.cluster
distributed = pytest.importorskip("distributed")  # the [cluster] extra (CI installs it)

REPO = Path(__file__).resolve().parents[2]


def test_study_on_a_dask_cluster_matches_one_process(tmp_path):
    from dyno.model import studies

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
        env = dict(os.environ, PYTHONPATH=str(REPO), DYNO_MODEL_CACHE=str(tmp_path / "cache"))
        out = tmp_path / "out"
        p = subprocess.run([sys.executable, "-m", "dyno", "model", "study", "friction", "--values", "0.3", "0.5",
                            "--points", "2", "--tol", "1e-2", "--scheduler", cl.scheduler_address,
                            "--out", str(out), "--json"], capture_output=True, text=True, env=env, timeout=900)
        assert p.returncode == 0, p.stderr[-2000:]
        doc = json.loads(p.stdout)
        assert doc["executor"].startswith("dask tcp://") and doc["tasks"] == {"computed": 2, "cached": 0}
        # the tasks ran on the cluster's workers (their compute time is on its scheduler's books)
        prefix = cl.scheduler.task_prefixes["run_task"]
        assert prefix.all_durations["compute"] > 0.5, dict(prefix.all_durations)
    with open(out / "study-friction-corrected.csv") as f:
        rows = list(csv.DictReader(f))
    local = studies.run_study("friction", values=(0.3, 0.5), n_points=2, tol=1e-2, use_cache=False)
    expected = [row for v in (0.3, 0.5) for row in local["series"][v]]
    assert len(rows) == len(expected) == 4
    for got, want in zip(rows, expected):
        assert got["converged"] == "True"
        assert float(got["efficiency_overall"]) == pytest.approx(want["efficiency_overall"], rel=1e-9)
