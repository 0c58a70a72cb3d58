#!/usr/bin/env python3
"""The drive grid (`dyno run --plan drive-grid`) on the simulated rig, over seeds.

Per seed: the run's test time (simulated s), wall time, cells measured / unreachable / not held, the
widest 95 % CI, the share of points whose CI holds the sim's truth and the median |efficiency - truth|;
then the totals, and the grid of the first seed (efficiency % per throttle and secondary setpoint).
Uses the synthetic part-throttle map (calibration/engine_maps/baja-10hp-representative-part-throttle.csv).

    python bench/bench_drive_grid.py [--seeds 10] [--plan drive-grid] [--quick]

``--quick`` (CI's smoke run): one seed.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dyno.session.root import RunSpec, run_test
from dyno.sim.rig_params import RigParams  # noqa: E402
from dyno.control.plans import plan_named  # noqa: E402

PART_MAP = Path(__file__).resolve().parent.parent / "calibration" / "engine_maps" / \
    "baja-10hp-representative-part-throttle.csv"


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--plan", default="drive-grid")
    ap.add_argument("--quick", action="store_true", help="CI smoke run: one seed")
    a = ap.parse_args()
    if a.quick:
        a.seeds = 1
    rows, all_pts, first = [], [], None
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, a.seeds + 1):
            t0 = time.perf_counter()
            # perfect knowledge (RigParams(ideal=True)): the CI coverage below is of the statistics alone;
            # the total uncertainty against a rig unlike its map is bench_uncertainty.py's
            r = run_test(RunSpec(sim=True, seed=seed, plan=plan_named(a.plan), out_dir=Path(tmp) / f"s{seed}",
                                    engine_map_path=PART_MAP, sim_params=RigParams(ideal=True)))
            wall = time.perf_counter() - t0
            cells = r["drive_grid"]["cells"]
            pts = [p for p in r["points"] if p.get("efficiency") is not None]
            all_pts += pts
            first = first or r["drive_grid"]
            rows.append({"seed": seed, "state": r["state"], "test_time_s": r["test_time_s"], "wall_s": wall,
                         "cells": len(cells), "measured": sum(c["index"] is not None for c in cells),
                         "unreachable": sum((c["reason"] or "").startswith("unreachable") for c in cells),
                         "covered": sum(abs(p["efficiency"] - p["efficiency_true"]) <= p["efficiency_ci95"] for p in pts),
                         "n": len(pts), "max_ci95": max((p["efficiency_ci95"] for p in pts), default=float("nan")),
                         "median_err": statistics.median(abs(p["efficiency"] - p["efficiency_true"]) for p in pts)
                         if pts else float("nan")})
    print("seed state  test_time_s  wall_s  cells measured unreachable  covered  max_ci95  median|err|")
    for x in rows:
        print(f"{x['seed']:4d} {x['state']:5s} {x['test_time_s']:11.1f} {x['wall_s']:7.1f} {x['cells']:6d} "
              f"{x['measured']:8d} {x['unreachable']:11d}  {x['covered']:3d}/{x['n']:<3d} {x['max_ci95']:9.4f} "
              f"{x['median_err']:11.4f}")
    cov = sum(abs(p["efficiency"] - p["efficiency_true"]) <= p["efficiency_ci95"] for p in all_pts)
    print(f"all seeds: truth inside the 95 % CI at {cov}/{len(all_pts)} points ({100 * cov / len(all_pts):.1f} %), "
          f"median |err| {statistics.median(abs(p['efficiency'] - p['efficiency_true']) for p in all_pts):.4f}, "
          f"widest CI {max(p['efficiency_ci95'] for p in all_pts):.4f}, test time "
          f"{min(x['test_time_s'] for x in rows):.0f}-{max(x['test_time_s'] for x in rows):.0f} s")
    print("\nseed 1 grid (efficiency %; '-' = no point):")
    at = {(c["throttle_frac"], c["setpoint_rpm"]): c for c in first["cells"]}
    print("setpoint rpm " + "".join(f"{'throttle ' + format(u, '.1f'):>14s}" for u in first["throttles"]))
    for sp in first["setpoints_rpm"]:
        vals = []
        for u in first["throttles"]:
            c = at.get((u, sp))
            e = c and c["efficiency"]
            vals.append(f"{100 * e:14.1f}" if e is not None else f"{'-':>14s}")
        print(f"{sp:12.0f} " + "".join(vals))
    return 0


if __name__ == "__main__":
    sys.exit(main())
