#!/usr/bin/env python3
"""Characterisations on the simulated rig against its truth: engagement plan and coast-down.

Part 1 runs ``--plan engagement`` for each shipped tune over several seeds and prints the engagement,
lock-up and shift-out rpm (measured - the sim's quasi-static truth, and the 95 % half-width) and the
full-shift ratio's relative error.  Part 2 runs ``--plan coast-down`` with a driven-side parasitic loss
switched on in the sim and prints the loss curve's largest relative error over the fitted speed range.
Part 3: the torque zero check with a drifting zero.

    python bench/bench_characterise.py [--seeds 3] [--quick]

``--quick`` (CI's smoke run): one seed; two tunes (the stock tune, whose ramps give the shift-out slope,
and the stiff primary spring, whose single load skips it); the zero check at one drift.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dyno.session.root import RunSpec, run_test  # noqa: E402
from dyno.control.plans import plan_named  # noqa: E402
from dyno.sim.rig_params import RigParams  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TUNES = ("cvtech-stock", "heavy-flyweights", "stiff-primary-spring")
QUICK_TUNES = ("cvtech-stock", "stiff-primary-spring")
DRIFTS = (0.0, 0.1, 1.0)
LOSS = (0.10, 4e-4, 1.2e-6)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--quick", action="store_true",
                    help="CI smoke run: one seed, two tunes, the zero check at one drift")
    a = ap.parse_args()
    tunes, drifts = TUNES, DRIFTS
    if a.quick:
        a.seeds, tunes, drifts = 1, QUICK_TUNES, (1.0,)
    tmp = Path(tempfile.mkdtemp(prefix="bench_char_"))
    try:
        _tables(a, tunes, drifts, tmp)
    finally:
        if a.quick:  # a smoke run leaves nothing behind
            shutil.rmtree(tmp, ignore_errors=True)


def _tables(a, tunes, drifts, tmp: Path) -> None:
    print("| tune | seed | engagement err rpm (±95 %) | lock-up err rpm | shift-out err rpm (±95 %) | "
          "full-shift ratio err % (±95 %) | shift-out slope rpm/N·m (±95 %) [truth] | sim s | wall s |")
    print("|---|---|---|---|---|---|---|---|---|")
    worst = {"eng": 0.0, "so": 0.0, "fs": 0.0}
    for tune in tunes:
        for seed in range(1, a.seeds + 1):
            t0 = time.monotonic()
            path = ROOT / "calibration" / "tunes" / f"{tune}.toml"
            r = run_test(RunSpec(sim=True, seed=seed, out_dir=tmp / f"{tune}-{seed}", tune_path=path,
                                    plan=plan_named("engagement"), sim_params=RigParams(cvt_tune_path=str(path))))
            wall = time.monotonic() - t0
            e = r["engagement_rpm"] - r["engagement_rpm_true"]
            lk = r["lockup_rpm"] - r["lockup_rpm_true"]
            so = r["shift_out_rpm"] - r["shift_out_rpm_true"]
            fs = 100 * (r["full_shift_ratio"] / r["full_shift_ratio_true"] - 1)
            worst["eng"], worst["so"], worst["fs"] = max(worst["eng"], abs(e)), max(worst["so"], abs(so)), \
                max(worst["fs"], abs(fs))
            rows = r.get("shift_out_vs_load") or []
            for row in rows[1:]:  # the heavier-load ramps count too
                worst["so"] = max(worst["so"], abs(row["shift_out_rpm"] - row["shift_out_rpm_true"]))
                worst["eng"] = max(worst["eng"], abs(row["engagement_rpm"] - row["engagement_rpm_true"]))
            fl, flt = r.get("shift_out_flatness") or {}, r.get("shift_out_flatness_true") or {}
            flat = (f"{fl['slope_rpm_per_nm']:.1f} (±{fl['slope_ci95_rpm_per_nm']:.1f}) "
                    f"[{flt['slope_rpm_per_nm']:.1f}]" if len(rows) >= 3 else f"{len(rows)} load(s): skipped")
            print(f"| {tune} | {seed} | {e:+.1f} (±{r['engagement_rpm_ci95']:.1f}) | {lk:+.1f} | "
                  f"{so:+.1f} (±{r['shift_out_rpm_ci95']:.1f}) | {fs:+.3f} "
                  f"(±{100 * r['full_shift_ratio_ci95'] / r['full_shift_ratio']:.3f}) | {flat} | "
                  f"{r['test_time_s']:.0f} | {wall:.1f} |")
    print(f"\nworst |error| (every ramp): engagement {worst['eng']:.1f} rpm, shift-out {worst['so']:.1f} rpm, "
          f"full-shift ratio {worst['fs']:.3f} %\n")
    print("| seed | fitted range rpm | revolutions | max loss error % | seen by gauge N·m (true 0.262) | wall s |")
    print("|---|---|---|---|---|---|")
    for seed in range(1, a.seeds + 1):
        t0 = time.monotonic()
        r = run_test(RunSpec(sim=True, seed=seed, out_dir=tmp / f"cd-{seed}", plan=plan_named("coast-down"),
                                sim_params=RigParams(driven_loss_nm=LOSS)))
        f = r["loss_fit"]
        print(f"| {seed} | {f['rpm_min']:.0f}-{f['rpm_max']:.0f} | {f['n_revolutions']} | "
              f"{100 * r['loss_torque_max_rel_error']:.2f} | {r['seen_nm']:.3f} ± {r['seen_ci95_nm']:.3f} | "
              f"{time.monotonic() - t0:.1f} |")
    print("\n| zero drift N·m/min | true drift N·m | measured N·m (±95 %) | flagged |")
    print("|---|---|---|---|")
    for drift in drifts:
        r = run_test(RunSpec(sim=True, seed=1, out_dir=tmp / f"z-{drift}", plan=plan_named("engagement"),
                                sim_params=RigParams(adc_zero_drift_nm_per_min=drift)))
        z = r["torque_zero"]
        true = drift * (z["after"]["t_mid_s"] - z["before"]["t_mid_s"]) / 60
        print(f"| {drift:g} | {true:.3f} | {z['drift_nm']:+.3f} (±{z['drift_ci95_nm']:.3f}) | {z['flagged']} |")


if __name__ == "__main__":
    main()
