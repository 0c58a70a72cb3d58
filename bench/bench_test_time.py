#!/usr/bin/env python3
"""Test time and uncertainty per plan on the simulated rig, and the speed hold's step responses.

Part 1 holds the secondary at 3,000 rpm, then steps the setpoint (+5 %, -5 %, -5 %, +5 %, -12 %) and
prints, per step: the time after which the speed stays within +-0.5 % of the setpoint, the overshoot (in %
of the setpoint), and the standard deviation over the last 3 s.  Part 2 runs the full steady test per plan
(speed-hold and thesis-step) over several seeds and prints points, test time, time per point, the widest
95 % CI, the share of points whose CI holds the sim's truth, and the median |efficiency - truth|.

Everything runs through the real-rig output code on mock pins (``--mock-pins``): the relay settle of
``rig.toml`` is honoured as on the rig.  The gains are ``rig.toml``'s [control].

    python bench/bench_test_time.py [--seeds 10] [--thesis-seeds 2] [--skip-steps]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import dyno.control.speed_hold as sh  # noqa: E402
from dyno.app import RunOptions, run_test  # noqa: E402
from dyno.control.controller import State  # noqa: E402
from dyno.control.outputs import APPLY, STOP  # noqa: E402
from dyno.control.plans import plan_named  # noqa: E402

STEPS = (3150.0, 3000.0, 2850.0, 2992.5, 2633.0)


def step_responses(tmp: Path, rig_path=None) -> list[dict]:
    rows = []

    async def plan(ctrl, *_a, **_k):
        hold = sh.SpeedHold(sh.gains_for(ctrl, "secondary"))
        ctrl._enter(State.STEP, "bench: contact")
        no_load = sh.secondary_rpm(ctrl, 1.0)
        ctrl.act.brake(APPLY)
        while sh.secondary_rpm(ctrl, 0.3) > 0.99 * no_load:
            await ctrl._sleep(0.02)
        ctrl.act.brake(STOP)
        target = {"rpm": 3000.0}
        task = asyncio.create_task(sh._hold_loop(ctrl, hold, target))
        await ctrl._sleep(15.0)
        for sp in STEPS:
            target["rpm"] = sp
            t0, trace = ctrl._now(), []
            while ctrl._now() - t0 < 8.0:
                await ctrl._sleep(0.05)
                trace.append((ctrl._now() - t0, sh.secondary_rpm(ctrl, 0.1)))
            outside = [t for t, r in trace if abs(r - sp) > 0.005 * sp]
            start = trace[0][1]
            beyond = [(r - sp) * (1 if sp > start else -1) for _, r in trace]
            rows.append({"from_rpm": start, "to_rpm": sp, "within_0p5pc_s": max(outside) if outside else 0.0,
                         "overshoot_pc": 100 * max(0.0, max(beyond)) / sp,
                         "sd_last3s_pc": 100 * statistics.pstdev(r for t, r in trace if t > 5.0) / sp})
        task.cancel()
        ctrl._enter(State.SETTLE, "bench")
        ctrl._enter(State.DONE, "bench done")

    real = sh.run_speed_hold
    sh.run_speed_hold = plan
    try:
        run_test(RunOptions(sim=True, seed=1, plan=plan_named("speed-hold"), out_dir=tmp / "steps", mock_pins=True,
                            rig_path=rig_path))
    finally:
        sh.run_speed_hold = real
    return rows


def summary(r: dict) -> dict:
    pts = r["points"]
    return {"state": r["state"], "points": len(pts), "test_time_s": r["test_time_s"],
            "max_ci95": max(p["efficiency_ci95"] for p in pts),
            "covered": sum(abs(p["efficiency"] - p["efficiency_true"]) <= p["efficiency_ci95"] for p in pts) / len(pts),
            "median_err": statistics.median(abs(p["efficiency"] - p["efficiency_true"]) for p in pts),
            "errs": [abs(p["efficiency"] - p["efficiency_true"]) for p in pts],
            "per_point_s": r["test_time_s"] / len(pts)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--thesis-seeds", type=int, default=2, help="the thesis step test takes ~9 simulated min a run")
    ap.add_argument("--skip-steps", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if not args.skip_steps:
            print("| setpoint step rpm | within +-0.5 % after s | overshoot % of setpoint | sd last 3 s % |")
            print("|---|---|---|---|")
            for row in step_responses(tmp):
                print(f"| {row['from_rpm']:.0f} -> {row['to_rpm']:.0f} | {row['within_0p5pc_s']:.2f} | "
                      f"{row['overshoot_pc']:.2f} | {row['sd_last3s_pc']:.2f} |", flush=True)
        print("\n| plan | seed | points | test time s | s/point | max CI95 | truth in CI | median err |")
        print("|---|---|---|---|---|---|---|---|")
        for plan, n in (("speed-hold", args.seeds), ("thesis-step", args.thesis_seeds)):
            rows = []
            for seed in range(1, n + 1):
                s = summary(run_test(RunOptions(sim=True, seed=seed, plan=plan_named(plan), mock_pins=True,
                                                out_dir=tmp / f"{plan}-{seed}")))
                rows.append(s)
                print(f"| {plan} | {seed} | {s['points']} | {s['test_time_s']:.0f} | {s['per_point_s']:.1f} | "
                      f"{s['max_ci95']:.5f} | {s['covered']:.0%} | {s['median_err']:.4f} |", flush=True)
            if rows:
                allpts = sum(r["points"] for r in rows)
                cov = sum(r["covered"] * r["points"] for r in rows) / allpts
                print(f"| **{plan}** | {len(rows)} seeds | {min(r['points'] for r in rows)}-"
                      f"{max(r['points'] for r in rows)} | {min(r['test_time_s'] for r in rows):.0f}-"
                      f"{max(r['test_time_s'] for r in rows):.0f} | "
                      f"{statistics.mean(r['per_point_s'] for r in rows):.1f} | "
                      f"{max(r['max_ci95'] for r in rows):.5f} | {cov:.0%} of {allpts} | "
                      f"{statistics.median(e for r in rows for e in r['errs']):.4f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
