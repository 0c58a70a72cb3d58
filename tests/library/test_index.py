"""The run library's index: filled at the end of every run, filtered, rebuilt (docs/library.md)."""

import json
import os
import sqlite3
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.control.api import TestPlan as Plan
from dyno.session.drills import parse_drill
from dyno.library import index as lib

REPO = Path(__file__).resolve().parents[2]
STOCK = REPO / "calibration" / "tunes" / "cvtech-stock.toml"
HEAVY = REPO / "calibration" / "tunes" / "heavy-flyweights.toml"
QUICK_PLAN = replace(Plan(), max_measure_s=3.0, warmup_s=2.0, target_points=4)


def _dyno(*args, runs_dir, cwd=REPO):
    env = dict(os.environ, DYNO_RUNS_DIR=str(runs_dir), PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=300)


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """A runs directory filled by real `dyno run` processes (short aborted runs, two tunes),
    one run written elsewhere with --out, and one complete quick run with points."""
    root = tmp_path_factory.mktemp("lib") / "runs"
    outside = tmp_path_factory.mktemp("elsewhere") / "heavy-out"
    procs = [
        ("--tune", STOCK, "--seed", 1),
        ("--tune", HEAVY, "--seed", 2),
        ("--tune", HEAVY, "--seed", 3, "--out", outside),
    ]
    results = [_dyno("run", "--sim", "--headless", "--json", "--drill", "overspeed@3", *a, runs_dir=root)
               for a in procs]
    for r in results:
        assert r.returncode == 3, r.stderr  # aborted by the drill: the exit code is the run's, not the index's
        assert "not indexed" not in r.stderr
    # a complete (short) run with points, written in-process into the runs directory; indexed by `dyno runs`
    run_test(RunSpec(sim=True, seed=4, out_dir=root / "quick", plan=QUICK_PLAN, tune_path=STOCK))
    return {"root": root, "outside": outside, "results": [json.loads(r.stdout) for r in results]}


def _runs(library, *args):
    r = _dyno("runs", "--json", *args, runs_dir=library["root"])
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)["runs"], r.stderr


def test_runs_tune_finds_the_runs_of_that_tune(library):
    runs, _ = _runs(library, "--tune", "heavy-flyweights")
    paths = {r["path"] for r in runs}
    assert paths == {str(Path(library["results"][1]["run_dir"]).resolve()), str(library["outside"].resolve())}
    assert all(r["tune_name"] == "heavy-flyweights" for r in runs)
    stock, _ = _runs(library, "--tune", "cvtech-stock")
    assert len(stock) == 2 and all(r["tune_name"] == "cvtech-stock" for r in stock)
    # by hash prefix too
    sha = runs[0]["tune_sha256"]
    assert {r["path"] for r in _runs(library, "--tune", sha[:12])[0]} == paths


def test_row_holds_what_the_run_recorded(library):
    runs, _ = _runs(library, "--points")
    by_name = {Path(r["path"]).name: r for r in runs}
    aborted = by_name["heavy-out"]
    assert aborted["state"] == "aborted" and aborted["exit_status"] == "abort"
    assert aborted["abort_cause"] == "overspeed"
    assert aborted["seed"] == 3 and aborted["mode"] == "sim" and aborted["protocol"] == "v2"
    assert aborted["calibration_date"] and aborted["calibration_slope_counts_per_nm"] > 0
    assert aborted["plan"]["max_points"] == Plan().max_points
    quick = by_name["quick"]
    assert quick["state"] == "done" and quick["n_points"] >= 2 and len(quick["points"]) == quick["n_points"]
    effs = [p["efficiency"] for p in quick["points"] if p["valid"]]
    assert quick["peak_efficiency"] == pytest.approx(max(effs))
    assert _runs(library, "--state", "done")[0] == [r for r in _runs(library)[0] if r["state"] == "done"]
    assert _runs(library, "--since", "2999-01-01")[0] == []
    assert len(_runs(library, "--since", "2000-01-01")[0]) == 4


def test_rebuilt_index_equals_incremental(library):
    _runs(library)  # make sure everything is indexed incrementally (hook + sync)
    conn = lib.connect(library["root"] / lib.INDEX_NAME)
    incremental = lib.dump(conn)
    conn.close()
    assert len(incremental["runs"]) == 4 and incremental["points"]
    r = _dyno("runs", "reindex", runs_dir=library["root"])
    assert r.returncode == 0 and "4 runs indexed" in r.stdout, r.stdout + r.stderr
    conn = lib.connect(library["root"] / lib.INDEX_NAME)
    assert lib.dump(conn) == incremental
    conn.close()


@pytest.mark.parametrize("damage", ["garbage", "truncated", "deleted", "other-schema"])
def test_damaged_index_rebuilds_with_one_line(library, tmp_path, damage):
    import shutil

    root = tmp_path / "runs"
    shutil.copytree(library["root"], root, ignore=shutil.ignore_patterns("library.sqlite*"))
    assert _dyno("runs", "reindex", root, runs_dir=tmp_path / "unused").returncode == 0
    db = root / lib.INDEX_NAME
    before = _dyno("runs", "--json", runs_dir=root)
    if damage == "garbage":
        db.write_bytes(b"not a database at all\n" * 100)
    elif damage == "truncated":
        db.write_bytes(db.read_bytes()[:200])
    elif damage == "deleted":
        db.unlink()
    else:
        conn = sqlite3.connect(db)
        conn.execute("PRAGMA user_version = 99")
        conn.commit()
        conn.close()
    r = _dyno("runs", "--json", runs_dir=root)
    assert r.returncode == 0 and "Traceback" not in r.stderr
    if damage != "deleted":
        assert len(r.stderr.strip().splitlines()) == 1 and "rebuilt from the run directories" in r.stderr
    # the copied runs live under root; the --out run outside survives only in an intact index
    inside = [x for x in json.loads(before.stdout)["runs"] if x["path"].startswith(str(root))]
    assert json.loads(r.stdout)["runs"] == inside


def test_index_failure_is_one_line_and_keeps_the_exit_code(tmp_path):
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("x")
    r = _dyno("run", "--sim", "--headless", "--drill", "overspeed@3", "--out", tmp_path / "run",
              runs_dir=not_a_dir)
    assert r.returncode == 3
    lines = [x for x in r.stderr.splitlines() if x.strip() and not x.startswith("dyno run: rig file ")]
    assert len(lines) == 1 and "not indexed" in lines[0] and "Traceback" not in r.stderr
    assert (tmp_path / "run" / "meta.json").is_file()


def test_bad_input_is_one_line_exit_2(tmp_path):
    for args in (["--since", "yesterday"], ["reindex", tmp_path / "missing"], ["frobnicate"]):
        r = _dyno("runs", *args, runs_dir=tmp_path)
        assert r.returncode == 2, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert not (tmp_path / lib.INDEX_NAME).exists()  # refused before anything is written
    a_file = tmp_path / "file"
    a_file.write_text("x")
    r = _dyno("runs", runs_dir=a_file)  # the runs directory is a file
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


def test_deleted_run_directory_leaves_the_listing(tmp_path):
    import shutil

    root = tmp_path / "runs"
    run_test(RunSpec(sim=True, seed=5, out_dir=root / "a", plan=QUICK_PLAN,
                        drills=[parse_drill("overspeed@3")]))
    conn = lib.open_library(root)
    assert lib.sync(conn, root) == 1 and len(lib.query(conn)) == 1
    shutil.rmtree(root / "a")
    assert lib.sync(conn, root) == 1 and lib.query(conn) == []
    conn.close()


def test_two_processes_indexing_at_once(library, tmp_path):
    """Runs ending together (two processes, a fresh index): every run indexed, nothing reported broken."""
    import shutil

    src = Path(library["results"][0]["run_dir"])
    dirs = []
    for k in range(24):
        d = tmp_path / "elsewhere" / f"r{k:02d}"
        shutil.copytree(src, d)
        dirs.append(str(d))
    root = tmp_path / "runs"
    script = ("import sys\nfrom dyno.library.index import index_after_run\n"
              "for d in sys.argv[1:]:\n"
              "    assert index_after_run(d, lambda line: print(line, file=sys.stderr))\n")
    env = dict(os.environ, DYNO_RUNS_DIR=str(root), PYTHONPATH=str(REPO))
    procs = [subprocess.Popen([sys.executable, "-c", script, *dirs[i::2]], env=env, stderr=subprocess.PIPE, text=True)
             for i in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=120)
        assert p.returncode == 0 and err == "", err
    conn = lib.connect(root / lib.INDEX_NAME)
    assert sorted(r["path"] for r in lib.query(conn)) == sorted(str(Path(d).resolve()) for d in dirs)
    conn.close()


from dyno.datapaths import legacy_data_dir, legacy_data_missing  # noqa: E402

LEGACY = legacy_data_dir() / "2019-04-18_run2"


@pytest.mark.skipif(legacy_data_missing() is not None, reason=str(legacy_data_missing()))
def test_import_legacy_is_indexed(tmp_path):
    root = tmp_path / "runs"
    r = _dyno("import-legacy", LEGACY, "--json", runs_dir=root)  # default --out: the runs directory
    assert r.returncode == 0, r.stderr
    run_dir = Path(json.loads(r.stdout)["run_dir"])
    assert run_dir.parent.resolve() == root.resolve()
    conn = lib.connect(root / lib.INDEX_NAME)  # indexed by the command itself, no sync
    (row,) = lib.query(conn)
    conn.close()
    assert row["mode"] == "legacy-import" and row["state"] in ("done", "success") and row["n_points"] > 0
    assert row["path"] == str(run_dir.resolve())


def test_ui_hook_indexes_what_is_new(library, tmp_path, monkeypatch):
    import shutil

    from dyno.session.after import index_run

    def _index(run_dir):
        index_run(run_dir, lambda line: None)

    root = tmp_path / "runs"
    shutil.copytree(library["root"] / "quick", root / "20260101-000000")
    monkeypatch.setenv("DYNO_RUNS_DIR", str(root))
    _index(None)  # the UI's run went to the runs directory under a name only the session knew
    _index(tmp_path / "never-started")  # no run there: nothing to do, nothing created
    conn = lib.connect(root / lib.INDEX_NAME)
    assert [r["name"] for r in lib.query(conn)] == ["20260101-000000"]
    conn.close()
    assert not (tmp_path / "never-started").exists()
