"""Slip-consistent inverse against the simulator's truth, and the belt table's first build.

    python bench/bench_inverse.py [--seeds 1 2 3] [--full 0 2] [--table-build] [--quick]

Per seed: a default simulated run (`dyno run --sim`), every valid point inverted
(closed-form slip at the run's tune), worst geometric-ratio and slip errors against
the sim's recorded truth, time per point.  ``--full I J``: the full-model tier at
those point indices (seconds per point; gross slip is a state).  ``--table-build``:
the sim's belt table at the stock tune's clamp from an empty cache (minutes).
Figures go to docs/belt-model.md ("Slip-consistent inverse").  ``--quick`` (CI's smoke run): seed 1 only.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dyno.model.inverse import invert_points  # noqa: E402
from dyno.tuning.tune import load_tune  # noqa: E402


def _run(seed: int, out: Path) -> list[dict]:
    subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--seed", str(seed), "--out", str(out), "--json"],
                   cwd=ROOT, check=True, capture_output=True)
    docs = map(json.loads, (out / "documents.jsonl").read_text().splitlines())
    return [d for d in docs if d["type"] == "point" and d.get("valid")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--full", type=int, nargs="*", default=[])
    ap.add_argument("--table-build", action="store_true")
    ap.add_argument("--quick", action="store_true", help="CI smoke run: seed 1 only")
    args = ap.parse_args()
    if args.quick:
        args.seeds = [1]
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            out = Path(tmp) / f"seed{seed}"
            pts = _run(seed, out)
            tune = load_tune(out / "tune.toml")
            t0 = time.perf_counter()
            res = invert_points(pts, tune)
            per_point_ms = 1e3 * (time.perf_counter() - t0) / max(len(pts), 1)
            er = max(abs(r.geometric_ratio / p["ratio_geometric_true"] - 1) for (_, r), p in zip(res, pts))
            es = max(abs(r.slip - p["belt_slip_true"]) for (_, r), p in zip(res, pts))
            states = {r.state for _, r in res}
            print(f"seed {seed}: {len(pts)} points, states {sorted(states)}, ratio error max {er:.2e} (relative), "
                  f"slip error max {es:.2e}, {per_point_ms:.1f} ms/point (closed-form slip)")
            for i in args.full:
                t0 = time.perf_counter()
                (_, r), = invert_points([pts[i]], tune, tier="full")
                p = pts[i]
                dev = r.geometric_ratio / p["ratio_geometric_true"] - 1 if r.ok else float("nan")
                print(f"  full tier, point {i} ({p['rpm_primary']:.0f} rpm, {r.primary_torque_nm:.1f} N*m, "
                      f"{r.primary_axial_force_n:.0f} N): {r.state}, ratio {dev:+.2%} from the truth, "
                      f"{time.perf_counter() - t0:.1f} s")
        if args.table_build:
            from dyno.sim.belt_table import build_belt_table
            from dyno.sim.rig_params import DEFAULT_TUNE, load_sim_tune

            tab = build_belt_table(cache_dir=Path(tmp) / "cache", tune=load_sim_tune(DEFAULT_TUNE))
            print(f"belt table at the stock tune's clamp: {tab.ok.size} cells, {int(tab.ok.sum())} solved, "
                  f"first build {tab.build_s:.1f} s")


if __name__ == "__main__":
    main()
