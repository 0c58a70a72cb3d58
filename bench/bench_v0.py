#!/usr/bin/env python3
"""Legacy protocol v0 under bit errors: does a corrupted frame ever end a test early?

The v0 frame's check is a 16-bit byte sum, so some corrupted frames pass it; the
reader's plausibility check (``dyno.acquisition.reader.implausible_v0``) and the
rpm-slot speed are what keep them from mattering.  For each seed this runs a full
simulated test with ``protocol = "v0"`` at BER 1e-3 and the same seed without faults,
and prints: how it ended, points (faulty vs clean), frames rejected as implausible,
corrupted frames the sim's audit saw accepted, and whether the test ended early
(fewer points than the clean run, or not by "secondary below").

    python bench/bench_v0.py [--seeds 20] [--ber 1e-3] [--quick]

``--quick`` (CI's smoke run): one seed, and a shorter test (about 6 points of at most 3 s each, 2 s
warm-up; it still ends by "secondary below"), faulty and clean alike.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dyno.session.root import RunSpec, run_test  # noqa: E402
from dyno.control.api import TestPlan  # noqa: E402
from dyno.sim.bus import BusFaults  # noqa: E402


def run_pair(seed: int, ber: float, tmp: Path, plan: TestPlan | None = None) -> dict:
    kw = {} if plan is None else {"plan": plan}
    faulty = run_test(RunSpec(sim=True, seed=seed, protocol="v0", faults=BusFaults(bit_error_rate=ber),
                                 out_dir=tmp / f"f{seed}", **kw))
    clean = run_test(RunSpec(sim=True, seed=seed, protocol="v0", out_dir=tmp / f"c{seed}", **kw))
    fr = faulty["frames"]
    implausible = sum(v for k, v in fr["rejected"].items() if k.startswith("implausible"))
    early = faulty["state"] != "done" or not faulty["reason"].startswith("secondary below") \
        or len(faulty["points"]) < len(clean["points"]) - 1
    return {"seed": seed, "state": faulty["state"], "reason": faulty["reason"], "points": len(faulty["points"]),
            "points_clean": len(clean["points"]), "implausible": implausible,
            "corrupted_accepted": fr["corrupted_accepted"], "accepted": fr["accepted"], "early": early}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--ber", type=float, default=1e-3)
    ap.add_argument("--quick", action="store_true",
                    help="CI smoke run: one seed, a shorter test (about 6 points, 3 s each at most)")
    args = ap.parse_args()
    plan = None
    if args.quick:
        args.seeds = 1
        plan = replace(TestPlan(), target_points=6, max_measure_s=3.0, warmup_s=2.0)
    rows = []
    print(f"{'seed':>4} {'state':>8} {'points':>6} {'clean':>5} {'implaus.':>8} {'corr.acc':>8} {'accepted':>8} early")
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, args.seeds + 1):
            r = run_pair(seed, args.ber, Path(tmp), plan)
            rows.append(r)
            print(f"{r['seed']:>4} {r['state']:>8} {r['points']:>6} {r['points_clean']:>5} {r['implausible']:>8} "
                  f"{r['corrupted_accepted']:>8} {r['accepted']:>8} {'YES' if r['early'] else 'no'}", flush=True)
    n_early = sum(r["early"] for r in rows)
    acc = sum(r["corrupted_accepted"] for r in rows)
    tot = sum(r["accepted"] for r in rows)
    print(f"\n{len(rows)} seeds at BER {args.ber:g}: {n_early} ended early; corrupted frames accepted "
          f"{acc} of {tot} accepted ({acc / max(tot, 1):.1e}), each within the plausibility bounds")
    return 1 if n_early else 0


if __name__ == "__main__":
    sys.exit(main())
