"""Speed of the run library's index: 200 run directories indexed from scratch, and one by one.

Makes a few short simulated runs (two tunes, one aborted by a drill), copies them
to N run directories with altered metadata (creation time, seed, tune name), then
times ``dyno runs reindex`` (in-process: ``reindex`` on a fresh index), the
end-of-run hook path (``index_run`` once per run) and a no-change ``sync``.

    python bench/bench_library.py [--n 200] [--keep DIR] [--quick]

Exit 1 when the index is wrong (a run missing from it, the rebuilt index unlike the one built run by run, a
no-change ``sync`` re-indexing something, the tune query finding another count) or the reindex misses its
goal (<= 10 s of wall time).  ``--quick`` (CI's smoke run, on whatever machine CI has): 20 run directories,
the index judged, its times printed, not judged.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dyno.session.root import RunSpec, run_test  # noqa: E402
from dyno.control.api import TestPlan  # noqa: E402
from dyno.session.drills import parse_drill  # noqa: E402
from dyno.library import index as lib  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
REINDEX_GOAL_S = 10.0  # wall time to reindex --n run directories (200: the library's figure)
TUNES = [REPO / "calibration" / "tunes" / "cvtech-stock.toml", REPO / "calibration" / "tunes" / "heavy-flyweights.toml"]


def make_seeds(where: Path) -> list[Path]:
    plan = replace(TestPlan(), max_measure_s=3.0, warmup_s=2.0, target_points=6)
    seeds = []
    for i, (tune, drills) in enumerate([(TUNES[0], []), (TUNES[1], []), (TUNES[0], [parse_drill("overspeed@3")])]):
        out = where / f"seed{i}"
        run_test(RunSpec(sim=True, seed=i, out_dir=out, plan=plan, tune_path=tune, drills=drills))
        seeds.append(out)
    return seeds


def fan_out(seeds: list[Path], root: Path, n: int) -> list[Path]:
    dirs = []
    for k in range(n):
        src = seeds[k % len(seeds)]
        dst = root / f"run-{k:04d}"
        shutil.copytree(src, dst)
        meta = json.loads((dst / "meta.json").read_text())
        meta["created_unix_s"] = 1.7e9 + 3600.0 * k  # one run an hour
        meta["seed"] = k
        (dst / "meta.json").write_text(json.dumps(meta))
        tune = dst / "tune.toml"
        if tune.exists():
            text = tune.read_text()
            name = f"tune-{k % 7}"
            text = "\n".join(f'name = "{name}"' if line.startswith("name = ") else line for line in text.splitlines())
            tune.write_text(text + "\n")
        dirs.append(dst)
    return dirs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--keep", type=Path, default=None, help="leave the runs here (default: a temporary directory)")
    ap.add_argument("--quick", action="store_true", help="CI smoke run: 20 run directories")
    args = ap.parse_args()
    if args.quick:
        args.n = 20
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench-library-"))
    try:
        t0 = time.perf_counter()
        seeds = make_seeds(work / "seeds")
        root = work / "runs"
        dirs = fan_out(seeds, root, args.n)
        print(f"{args.n} run directories from {len(seeds)} simulated runs in {time.perf_counter() - t0:.1f} s")
        n_points = sum(len([1 for line in (d / "documents.jsonl").read_text().splitlines() if '"point"' in line])
                       for d in dirs)

        conn = lib.open_library(root)
        t = time.perf_counter()
        n = lib.reindex(conn, root)
        t_reindex = time.perf_counter() - t
        rebuilt = lib.dump(conn)
        conn.close()
        for suffix in ("", "-wal", "-shm"):
            Path(f"{root / lib.INDEX_NAME}{suffix}").unlink(missing_ok=True)

        conn = lib.open_library(root)
        t = time.perf_counter()
        for d in dirs:
            lib.index_run(conn, d)  # as the end-of-run hook does, one transaction per run
        t_each = time.perf_counter() - t
        same = lib.dump(conn) == rebuilt
        t = time.perf_counter()
        changed = lib.sync(conn, root)
        t_sync = time.perf_counter() - t
        t = time.perf_counter()
        found = lib.query(conn, tune="tune-3")
        t_query = time.perf_counter() - t
        conn.close()
        want_found = sum(1 for k in range(args.n) if k % 7 == 3)  # fan_out names the tunes tune-(k % 7)
        fast = args.quick or t_reindex <= REINDEX_GOAL_S
        print(f"reindex: {n} runs, {n_points} points in {t_reindex:.2f} s (goal <= {REINDEX_GOAL_S:g} s: "
              f"{'not judged (--quick)' if args.quick else 'met' if fast else 'MISSED'})")
        print(f"one by one (end-of-run hook): {t_each:.2f} s; rebuilt == incremental: {same}")
        print(f"sync with nothing changed: {t_sync * 1e3:.0f} ms ({changed} re-indexed); "
              f"query --tune tune-3: {len(found)} runs (of {want_found}) in {t_query * 1e3:.1f} ms")
        right = same and n == args.n and changed == 0 and len(found) == want_found
        print(f"index: {n}/{args.n} runs, rebuilt == incremental {same}, sync re-indexed {changed}, query "
              f"{len(found)}/{want_found} -> {'ok' if right else 'FAIL'}")
        return 0 if right and fast else 1
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
