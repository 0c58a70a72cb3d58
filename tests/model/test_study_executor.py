"""Model studies as tasks (issue 25, item 5): one executor interface (this process, a local process pool,
Dask), a cache keyed by inputs and the model's code, resumable after an interruption.  The cluster test
(a real dask.distributed LocalCluster) is in test_study_cluster.py and runs on its own in CI."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from dyno.model import studies
from dyno.model.executor import InlineExecutor, PoolExecutor, make_executor
from dyno.model.params import TABLE_6_1, TABLE_6_1_POINT
from dyno.model.study_tasks import SweepTask, task_key

REPO = Path(__file__).resolve().parents[2]
#: a small study: two values, two ratios, a loose tolerance (each task: its homotopy and two solves)
STUDY = dict(name="friction", values=(0.3, 0.4), n_points=2, tol=1e-2)
CLI_STUDY = ["model", "study", "friction", "--values", "0.3", "0.4", "--points", "2", "--tol", "1e-2"]


class Interrupted(Exception):
    pass


@pytest.fixture(scope="module")
def inline_study(tmp_path_factory):
    """The study in this process, interrupted (as by Ctrl+C) after its first task, then run again."""
    cache = tmp_path_factory.mktemp("study-cache")
    seen = []

    def stop_after_first(done, total, label, cached):
        seen.append((label, cached))
        raise Interrupted  # the first finished task is stored before progress is told

    with pytest.raises(Interrupted):
        studies.run_study(**STUDY, cache_dir=cache, progress=stop_after_first)
    stored = list((cache / "studies").glob("*.json"))
    result = studies.run_study(**STUDY, cache_dir=cache)
    return {"first": seen, "stored_after_interrupt": len(stored), "result": result, "cache": cache}


def test_an_interrupted_study_resumes_with_what_it_had(inline_study):
    assert inline_study["first"] == [("friction=0.3", False)] and inline_study["stored_after_interrupt"] == 1
    r = inline_study["result"]
    assert r["tasks"] == {"computed": 1, "cached": 1}  # only the task still missing was solved again
    for value in STUDY["values"]:
        rows = r["series"][value]
        assert len(rows) == 2 and all(row["converged"] for row in rows)
        # the physics: power flows one way, the belt loses a little of it
        assert all(0.5 < row["efficiency_overall"] < 1.0 for row in rows)
        # and the secondary's torque is the primary's over the speed ratio, less the losses
        for row in rows:
            speed_ratio = row["primary_speed_rpm"] / row["secondary_speed_rpm"]
            assert row["secondary_torque_nm"] <= row["primary_torque_nm"] * speed_ratio * 1.0001


def test_the_key_follows_the_inputs_and_the_model_code_not_the_warm_start(monkeypatch):
    t = SweepTask("x", TABLE_6_1, TABLE_6_1_POINT, (1.2, 1.0), tol=1e-2)
    k = task_key(t)
    assert task_key(replace(t, guess=object(), label="other")) == k
    assert task_key(replace(t, tol=1e-3)) != k and task_key(replace(t, ratios=(1.2, 0.9))) != k
    assert task_key(replace(t, params=TABLE_6_1.with_belt(friction_coefficient=0.41))) != k
    from dyno.model import cache_keys

    monkeypatch.setattr(cache_keys, "model_code_hash", lambda: "a changed model")
    assert task_key(t) != k  # a changed model solves everything again


def _square(x):
    return x * x


def test_executors_give_every_result_once_with_its_index():
    for ex in (InlineExecutor(), PoolExecutor(2)):
        try:
            got = dict(ex.map_unordered(_square, [3, 1, 4, 1, 5]))
        finally:
            ex.close()
        assert got == {0: 9, 1: 1, 2: 16, 3: 1, 4: 25}
    assert make_executor(1).name == "inline" and make_executor(3).name == "pool of 3"


def _csv_rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_cli_study_on_a_process_pool_matches_this_process_and_reuses_its_cache(inline_study, tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO), DYNO_MODEL_CACHE=str(tmp_path / "cache"))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "dyno", *CLI_STUDY, "--jobs", "2", "--out", str(out), "--json"]
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
    assert p.returncode == 0, p.stderr[-2000:]
    doc = json.loads(p.stdout)
    assert doc["executor"] == "pool of 2" and doc["tasks"] == {"computed": 2, "cached": 0}
    assert {Path(f).suffix for f in doc["files"]} >= {".csv", ".png"}
    rows = _csv_rows(out / "study-friction-corrected.csv")
    expected = [row for v in STUDY["values"] for row in inline_study["result"]["series"][v]]
    assert len(rows) == len(expected)
    for got, want in zip(rows, expected):  # the same solves, wherever they ran
        assert float(got["friction"]) in STUDY["values"]
        assert float(got["efficiency_overall"]) == pytest.approx(want["efficiency_overall"], rel=1e-9)
    again = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert again.returncode == 0 and json.loads(again.stdout)["tasks"] == {"computed": 0, "cached": 2}


def test_cli_scheduler_that_is_not_there_is_one_line(tmp_path):
    pytest.importorskip("distributed")  # (the [cluster] extra; CI installs it)
    env = dict(os.environ, PYTHONPATH=str(REPO), DYNO_MODEL_CACHE=str(tmp_path / "cache"))
    p = subprocess.run([sys.executable, "-m", "dyno", *CLI_STUDY, "--scheduler", "tcp://127.0.0.1:9",
                        "--out", str(tmp_path / "o")], capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "--scheduler" in p.stderr, p.stderr
