"""Is the simulated rig the real one?  The default thesis-step run against the thesis rig's 2019 logs.

    python bench/bench_fidelity.py [--seed 4] [--quick] [--json]

1. The default simulated rig (no --sim flags) runs the shipped ``thesis-step`` plan on ``--seed``.
2. The 2019 logs are read here, independently of ``dyno import-legacy``: per steady point N of each run
   (point 0 was taken before loading and is discarded, as the thesis team did) the mean of the Arduino's
   instantaneous rpm over its distinct timestamps (the Pi polled faster than the edges came, so rows repeat),
   for the primary and the secondary; the speed ratio is rpm_primary / rpm_secondary.
3. At each logged point whose speed ratio lies inside the simulated run's range, the simulated engine speed is
   interpolated linearly in speed ratio; the RMS of (simulated - logged) per run.

Criteria (exit 1 when one fails): for runs 2 and 3, >= 5 logged points inside the simulated range and an RMS
<= 75 rpm (issue 35's hard limit; run 4, whose torque channel is broken but whose speeds are good, is shown
too); the simulated engine speed falls with speed ratio above 1:1 (a least-squares slope < 0 over >= 3 points);
the lowest simulated speed ratio <= 0.60 (the logs' overdrive reaches 0.547).  Without ``--quick`` the full
belt model (``dyno model overlay RUN --tier full``) must also predict >= 90 % of the run's points and every
point above 15 N·m.  ``--quick``: the fidelity alone (the CI smoke run; the overlay solves for minutes).
Needs the logs (``$DYNO_LEGACY_DATA`` or ``../shared/data/vt-cvt-dyno-2019``); without them it says so in one
line ("skipped") and exits 0.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from dyno.datapaths import legacy_data_dir, legacy_data_missing  # noqa: E402

RUNS = ("2019-04-18_run2", "2019-04-18_run3", "2019-04-18_run4")
JUDGED = ("2019-04-18_run2", "2019-04-18_run3")
RMS_LIMIT_RPM = 75.0
MIN_INSIDE = 5
MIN_ABOVE_1 = 3
LOWEST_RATIO_MAX = 0.60
FULL_SHARE_MIN = 0.90
HEAVY_NM = 15.0


def _read_pairs(path: Path) -> np.ndarray:
    rows = []
    if path.is_file():
        with path.open(newline="") as f:
            for r in csv.reader(f):
                try:
                    rows.append((float(r[0]), float(r[1])))
                except (ValueError, IndexError):
                    continue  # a header or a torn line (real data)
    return np.asarray(rows, dtype=float).reshape(-1, 2)


def _mean_distinct(a: np.ndarray) -> float:
    if len(a) < 3:
        return math.nan
    keep = np.r_[True, np.diff(a[:, 0]) != 0]
    return float(np.mean(a[keep, 1]))


def logged_points(run_dir: Path) -> list[dict]:
    """The steady points of one logged run: engine and secondary rpm and their speed ratio."""
    ns = sorted(int(m.group(1)) for p in run_dir.glob("P_*.csv") if (m := re.fullmatch(r"P_(\d+)\.csv", p.name)))
    out = []
    for n in ns:
        if n == 0:
            continue
        rp = _mean_distinct(_read_pairs(run_dir / f"P_{n}.csv"))
        rs = _mean_distinct(_read_pairs(run_dir / f"S_{n}.csv"))
        if rp > 1000.0 and rs > 300.0:  # a degenerate file (real data): not a point
            out.append({"n": n, "rpm_primary": rp, "rpm_secondary": rs, "speed_ratio": rp / rs})
    return out


def simulated_run(seed: int, out_dir: Path) -> dict:
    """The default simulated rig's thesis-step run (in this process, on virtual time)."""
    from dyno.session.root import RunSpec, run_test
    from dyno.control.plans import plan_named

    return run_test(RunSpec(sim=True, seed=seed, plan=plan_named("thesis-step"), out_dir=out_dir))


def compare(sim_points: list[dict], logs: dict[str, list[dict]]) -> dict:
    pts = [p for p in sim_points if p.get("valid", True) and p["rpm_secondary"] > 0]
    sr = np.array([p["rpm_primary"] / p["rpm_secondary"] for p in pts])
    se = np.array([p["rpm_primary"] for p in pts])
    order = np.argsort(sr)
    sr, se = sr[order], se[order]
    above = sr > 1.0
    slope = float(np.polyfit(sr[above], se[above], 1)[0]) if above.sum() >= 2 else math.nan
    runs = {}
    for name, lp in logs.items():
        inside = [q for q in lp if sr[0] <= q["speed_ratio"] <= sr[-1]]
        res = np.array([np.interp(q["speed_ratio"], sr, se) - q["rpm_primary"] for q in inside])
        lr = np.array([q["speed_ratio"] for q in lp])
        le = np.array([q["rpm_primary"] for q in lp])
        la = lr > 1.0
        runs[name] = {"points": len(lp), "inside": int(len(inside)),
                      "rms_rpm": float(np.sqrt(np.mean(res ** 2))) if len(res) else math.nan,
                      "mean_rpm": float(np.mean(res)) if len(res) else math.nan,
                      "slope_above_1_rpm_per_ratio": float(np.polyfit(lr[la], le[la], 1)[0]) if la.sum() >= 2 else math.nan,
                      "lowest_speed_ratio": float(lr.min()) if len(lr) else math.nan}
    return {"sim_points": int(len(sr)), "sim_points_above_1": int(above.sum()),
            "sim_slope_above_1_rpm_per_ratio": slope, "sim_lowest_speed_ratio": float(sr[0]) if len(sr) else math.nan,
            "sim_highest_speed_ratio": float(sr[-1]) if len(sr) else math.nan, "runs": runs}


def full_model_share(run_dir: Path, sim_points: list[dict]) -> dict:
    """``dyno model overlay RUN --tier full --json`` as the user runs it: the share of points it predicts
    (a finite full-model efficiency), overall and above 15 N·m of the run's measured torque."""
    proc = subprocess.run([sys.executable, "-m", "dyno", "model", "overlay", str(run_dir), "--tier", "full", "--json"],
                          capture_output=True, text=True, cwd=REPO, timeout=3600)
    if proc.returncode != 0:
        return {"error": (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1]}
    rows = json.loads(proc.stdout)["points"]
    torque = {p["index"]: p["torque_secondary_nm"] for p in sim_points}

    def predicted(r) -> bool:
        return isinstance(r.get("efficiency"), (int, float)) and math.isfinite(r["efficiency"])

    heavy = [r for r in rows if torque.get(r["index"], 0.0) > HEAVY_NM]
    return {"points": len(rows), "predicted": sum(map(predicted, rows)),
            "share": sum(map(predicted, rows)) / len(rows) if rows else math.nan,
            "above_15nm": len(heavy), "above_15nm_predicted": sum(map(predicted, heavy))}


def verdicts(c: dict, full: dict | None) -> list[tuple[str, bool]]:
    out = []
    for name in JUDGED:
        r = c["runs"][name]
        out.append((f"{name}: {r['inside']} logged points inside the simulated range (>= {MIN_INSIDE})",
                    r["inside"] >= MIN_INSIDE))
        out.append((f"{name}: engine speed RMS {r['rms_rpm']:.0f} rpm (<= {RMS_LIMIT_RPM:.0f})",
                    r["rms_rpm"] <= RMS_LIMIT_RPM))
    out.append((f"simulated engine speed against speed ratio above 1:1: slope {c['sim_slope_above_1_rpm_per_ratio']:.0f} "
                f"rpm per unit over {c['sim_points_above_1']} points (< 0, >= {MIN_ABOVE_1} points)",
                c["sim_slope_above_1_rpm_per_ratio"] < 0 and c["sim_points_above_1"] >= MIN_ABOVE_1))
    out.append((f"lowest simulated speed ratio {c['sim_lowest_speed_ratio']:.3f} (<= {LOWEST_RATIO_MAX})",
                c["sim_lowest_speed_ratio"] <= LOWEST_RATIO_MAX))
    if full is not None:
        ok = "error" not in full
        out.append((f"full model predicts {full.get('predicted')}/{full.get('points')} points (>= {FULL_SHARE_MIN:.0%})"
                    if ok else f"full model overlay failed: {full['error']}", ok and full["share"] >= FULL_SHARE_MIN))
        if ok:
            out.append((f"full model predicts {full['above_15nm_predicted']}/{full['above_15nm']} points above "
                        f"{HEAVY_NM:.0f} N·m (all)", full["above_15nm_predicted"] == full["above_15nm"]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--quick", action="store_true", help="the fidelity alone (no full-model overlay)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    missing = legacy_data_missing()
    if missing:  # (one line, exit 0: the smoke run reports it as skipped, as for a missing toolchain)
        print(f"bench_fidelity: skipped ({missing})")
        return 0
    data = legacy_data_dir()
    logs = {name: logged_points(data / name) for name in RUNS}
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "thesis-step"
        summary = simulated_run(args.seed, run_dir)
        c = compare(summary["points"], logs)
        full = None if args.quick else full_model_share(run_dir, summary["points"])
    checks = verdicts(c, full)
    if args.json:
        print(json.dumps({"seed": args.seed, "state": summary["state"], **c, "full_model": full,
                          "checks": [{"check": t, "ok": ok} for t, ok in checks]}, indent=1))
    else:
        print(f"default simulated rig, thesis-step, seed {args.seed}: {summary['state']}, {c['sim_points']} points, "
              f"speed ratio {c['sim_lowest_speed_ratio']:.3f}..{c['sim_highest_speed_ratio']:.3f}")
        print("| logged run | points | inside | RMS rpm | mean rpm | logged slope >1:1 | logged lowest ratio |")
        print("|---|---|---|---|---|---|---|")
        for name, r in c["runs"].items():
            print(f"| {name} | {r['points']} | {r['inside']} | {r['rms_rpm']:.0f} | {r['mean_rpm']:+.0f} | "
                  f"{r['slope_above_1_rpm_per_ratio']:.0f} | {r['lowest_speed_ratio']:.3f} |")
        for text, ok in checks:
            print(f"{'PASS' if ok else 'FAIL'}  {text}")
    return 0 if summary["state"] == "done" and all(ok for _, ok in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
