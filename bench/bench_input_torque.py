"""Map-free efficiency (issue 27): both paths' ``efficiency_interval95`` judged over many simulated rigs.

Each seed is a different rig (:mod:`dyno.sim.world`, as in ``bench_uncertainty.py``): its engine differs
from the shipped map (a smooth deviation, the simulator's own 4.4 % sd), its day is drawn, and each torque
channel's gain differs from its calibration (the brake-side gauge's as the simulator models it: re-seating
scatter and thermal drift; the input channel's by the history's reproducibility).  The rig is ``hardware/rig-input-torque.toml``
with a BME280 (the air known): the engine cradle's load cell is fitted, so every point carries the input
path's efficiency ``P_out / (T_in w_p)`` with its ``efficiency_u95`` and, beside it, the engine map's
(``efficiency_engine_map``, ``efficiency_engine_map_u95``).  Both are judged against the simulated truth
on the same points.  Also judged: the engine's measured torque (``torque_input_nm ± torque_input_u95_nm``)
against the simulated engine's true torque, and the map's error the measurement reveals.

Printed: coverage of each path's interval95 (95 % nominal), normalised errors, the mean U95 (the interval's
half-width) for each path; the calibration
reproducibility at which the input path's mean half-width would be 2 pp (from the stated terms); and with
``--repro R`` the whole bench at reproducibility R (both channels' histories and the rigs' sensors scatter
by R instead of 1.6 %), to check that claim on the truth.

Pass criteria (exit 1 when one fails, 0 when all hold): the input path's efficiency coverage by its
``efficiency_interval95`` ≥ 0.90 and the engine's measured torque's coverage by ``torque_input_u95_nm`` ≥ 0.90
(95 % nominal); with ``--quick`` (3 seeds) ≥ 0.75 each, a smoke check.  ``--miscalibrate-input REL`` hands
the host an input-channel calibration history whose slopes are all off by REL (a deliberately broken
input: the criteria must then fail).

    python bench/bench_input_torque.py              # 100 seeds (about 20 min on 2 cores)
    python bench/bench_input_torque.py --repro 0.007 --seeds 50
    python bench/bench_input_torque.py --quick      # 3 seeds
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from bench_uncertainty import SHORT_PLAN  # noqa: E402  (the same short speed-hold plan)


def _scaled_history(src: Path, dst: Path, repro: float) -> None:
    """``src``'s history with its slopes' scatter about their mean scaled to relative sd ``repro``."""
    import csv
    import io

    rows = list(csv.DictReader(io.StringIO(src.read_text())))
    slopes = [float(r["slope_counts_per_nm"]) for r in rows]
    mean, sd = statistics.fmean(slopes), statistics.stdev(slopes)
    k = repro * mean / sd
    latest = slopes[-1]  # the latest entry (the one used) stays; the others move toward/away from it
    for r, s in zip(rows, slopes):
        r["slope_counts_per_nm"] = repr(latest + (s - latest) * k)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]))
    w.writeheader()
    w.writerows(rows)
    dst.write_text(buf.getvalue())


def _scaled_slopes(src: Path, dst: Path, factor: float) -> None:
    """``src``'s history with every slope times ``factor`` (a calibration the channel does not have)."""
    import csv
    import io

    rows = list(csv.DictReader(io.StringIO(src.read_text())))
    for r in rows:
        r["slope_counts_per_nm"] = repr(float(r["slope_counts_per_nm"]) * factor)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]))
    w.writeheader()
    w.writerows(rows)
    dst.write_text(buf.getvalue())


CRITERION_COVERAGE, CRITERION_COVERAGE_QUICK = 0.90, 0.75


def verdicts(input_path: dict, torque: dict, quick: bool) -> list[str]:
    """The pass criteria (module docstring): one line each, 'FAIL' in it when it fails."""
    need = CRITERION_COVERAGE_QUICK if quick else CRITERION_COVERAGE
    out = []
    for what, cov in (("input path efficiency", input_path["coverage"]), ("engine torque", torque["coverage"])):
        ok = cov >= need  # (NaN: nothing judged, fails)
        out.append(f"{'pass' if ok else 'FAIL'}: {what}: coverage {cov:.3f} (criterion >= {need:.2f})")
    return out


def setup_files(tmp: Path, repro: float | None, miscalibrate: float | None = None) -> dict:
    """The rig file (input channel + BME280) and, at ``repro``, both channels' histories."""
    rig = (REPO / "hardware" / "rig-input-torque.toml").read_text().replace('sensor = "none"', 'sensor = "bme280"', 1)
    files = {"calibration": str(REPO / "calibration" / "torque_calibration.csv")}
    if miscalibrate is not None:  # the host told a wrong input calibration (the broken-input check)
        bad = tmp / "input_torque_calibration_off.csv"
        _scaled_slopes(REPO / "calibration" / "input_torque_calibration.csv", bad, 1.0 + miscalibrate)
        rig = rig.replace('calibration = "calibration/input_torque_calibration.csv"', f'calibration = "{bad}"')
    if repro is not None:
        out_hist, in_hist = tmp / "torque_calibration.csv", tmp / "input_torque_calibration.csv"
        _scaled_history(REPO / "calibration" / "torque_calibration.csv", out_hist, repro)
        _scaled_history(REPO / "calibration" / "input_torque_calibration.csv", in_hist, repro)
        rig = rig.replace('calibration = "calibration/input_torque_calibration.csv"', f'calibration = "{in_hist}"')
        files["calibration"] = str(out_hist)
    (tmp / "rig.toml").write_text(rig)
    (tmp / "short.toml").write_text(SHORT_PLAN)
    files.update(rig=str(tmp / "rig.toml"), plan=str(tmp / "short.toml"), repro=repro)
    return files


def one_seed(seed: int, tmp: str, files: dict) -> dict:
    from dyno.session.root import RunSpec, run_test
    from dyno.control.plans import plan_named
    from dyno.sim.rig_params import RigParams

    params = None
    if files["repro"] is not None:  # the rigs' sensors scatter as their histories now say
        params = RigParams(adc_gain_drift_rel_sd=files["repro"], input_gain_drift_rel_sd=files["repro"])
    result = run_test(RunSpec(sim=True, seed=seed, out_dir=Path(tmp) / f"seed{seed}", rig_path=Path(files["rig"]),
                                 calibration_path=Path(files["calibration"]), plan=plan_named(files["plan"]),
                                 sim_params=params))
    rows = []
    for p in result["points"]:
        if p.get("efficiency") is None or p.get("efficiency_true") is None or not p.get("valid", True):
            continue
        rows.append({k: p.get(k) for k in (
            "rpm_primary", "efficiency_true", "efficiency", "efficiency_u95", "efficiency_ci95", "efficiency_interval95",
            "efficiency_engine_map", "efficiency_engine_map_u95", "efficiency_engine_map_interval95", "torque_input_nm", "torque_input_u95_nm",
            "torque_input_true_nm", "efficiency_u95_terms")})
    w = result["sim_world"]
    return {"seed": seed, "rows": rows, "state": result["state"],
            "map_dev": [w["engine_dev_rpm"], w["engine_dev_rel"], w["engine_ageing_loss_frac"]]}


def judge(runs, eff_key: str, u95_key: str) -> dict:
    """Coverage of the truth by the figure's ``<eff_key>_interval95`` (the point's one 95 % statement; its
    ``u95_key`` is half its width, used for the normalised errors)."""
    z, covered, half, per_run = [], [], [], []
    for run in runs:
        mids = []
        for r in run["rows"]:
            eff, u95, iv = r.get(eff_key), r.get(u95_key), r.get(f"{eff_key}_interval95")
            if eff is None or u95 is None or not u95 > 0 or not iv or None in iv:
                continue
            err = eff - r["efficiency_true"]
            z.append(err / (u95 / 1.96))
            inside = iv[0] <= r["efficiency_true"] <= iv[1]
            covered.append(inside)
            half.append(u95)
            mids.append(inside)
        if mids:
            per_run.append(mids[len(mids) // 2])
    n = len(z)
    return {"path": eff_key, "points": n, "runs": len(per_run), "coverage": sum(covered) / n if n else math.nan,
            "coverage_per_run": sum(per_run) / len(per_run) if per_run else math.nan,
            "z_mean": statistics.fmean(z) if n else math.nan, "z_sd": statistics.stdev(z) if n > 1 else math.nan,
            "mean_u95": statistics.fmean(half) if n else math.nan}


def judge_torque(runs) -> dict:
    """The engine's measured torque against its true torque, and the map error the measurement reveals."""
    covered, half_rel, z = [], [], []
    for run in runs:
        for r in run["rows"]:
            t, u, tt = r.get("torque_input_nm"), r.get("torque_input_u95_nm"), r.get("torque_input_true_nm")
            if t is None or u is None or tt is None:
                continue
            covered.append(abs(t - tt) <= u)
            half_rel.append(u / tt)
            z.append((t - tt) / (u / 1.96))
    n = len(covered)
    return {"points": n, "coverage": sum(covered) / n if n else math.nan,
            "mean_u95_rel": statistics.fmean(half_rel) if n else math.nan,
            "z_sd": statistics.stdev(z) if n > 1 else math.nan}


def repro_for_half_width(runs, target: float) -> float:
    """The reproducibility r (both channels' slopes) at which the input path's mean U95 is ``target``,
    from each point's stated terms: U95(r)^2 = CI^2 + (2 eta)^2 (2 r^2 + tare + cradle)."""
    pts = []
    for run in runs:
        for r in run["rows"]:
            t = r.get("efficiency_u95_terms") or {}
            if r.get("efficiency_u95") is None or "calibration_input" not in t:
                continue
            eff = r["efficiency"]
            pts.append((eff, t["statistical"], t["cradle"]))
    if not pts:
        return math.nan

    def mean_u(rr: float) -> float:
        return statistics.fmean(math.sqrt(ci * ci + cr * cr + (2 * eff) ** 2 * 2 * rr * rr) for eff, ci, cr in pts)

    if mean_u(0.0) >= target:
        return 0.0
    lo, hi = 0.0, 0.1
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mean_u(mid) < target else (lo, mid)
    return lo


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--repro", type=float, default=None,
                    help="both channels' calibration reproducibility (relative sd; default: the shipped histories')")
    ap.add_argument("--quick", action="store_true", help="3 seeds: a smoke run")
    ap.add_argument("--miscalibrate-input", type=float, default=None, metavar="REL",
                    help="hand the host an input calibration history with every slope off by REL (a broken input)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args(argv)
    n = 3 if args.quick else args.seeds
    if args.repro is not None and not 0.0 < args.repro < 0.2:
        print("bench_input_torque: --repro: a relative standard deviation in (0, 0.2)", file=sys.stderr)
        return 2
    if args.miscalibrate_input is not None and not -0.5 < args.miscalibrate_input < 0.5:
        print("bench_input_torque: --miscalibrate-input: a relative error in (-0.5, 0.5)", file=sys.stderr)
        return 2
    seeds = list(range(args.first_seed, args.first_seed + n))
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="bench-input-") as tmp:
        files = setup_files(Path(tmp), args.repro, args.miscalibrate_input)
        if args.jobs > 1:
            with ProcessPoolExecutor(args.jobs) as pool:
                runs = list(pool.map(one_seed, seeds, [tmp] * n, [files] * n))
        else:
            runs = [one_seed(s, tmp, files) for s in seeds]
    wall_s = time.monotonic() - t0
    paths = [judge(runs, "efficiency", "efficiency_u95"), judge(runs, "efficiency_engine_map", "efficiency_engine_map_u95")]
    torque = judge_torque(runs)
    r2 = repro_for_half_width(runs, 0.02)
    repro = "shipped histories (1.6 %)" if args.repro is None else f"{100 * args.repro:.2f} %"
    off = "" if args.miscalibrate_input is None else f", input calibration off by {args.miscalibrate_input:+.1%}"
    print(f"bench_input_torque: {n} seeds ({seeds[0]}..{seeds[-1]}), rig-input-torque + BME280, short speed-hold "
          f"plan, calibration reproducibility {repro}{off}, {sum(r['state'] == 'done' for r in runs)} runs done, "
          f"{wall_s:.0f} s wall")
    print(f"{'path':<13}{'points':>7}{'runs':>6}{'coverage':>10}{'per run':>9}{'z mean':>8}{'z sd':>7}{'mean U95 pp':>13}")
    for c, name in zip(paths, ("input_torque", "engine_map")):
        print(f"{name:<13}{c['points']:>7}{c['runs']:>6}{c['coverage']:>10.3f}{c['coverage_per_run']:>9.3f}"
              f"{c['z_mean']:>8.2f}{c['z_sd']:>7.2f}{100 * c['mean_u95']:>13.2f}")
    print(f"engine torque measured vs true: {torque['points']} points, coverage {torque['coverage']:.3f}, "
          f"mean U95 {100 * torque['mean_u95_rel']:.2f} % of the torque, z sd {torque['z_sd']:.2f}")
    print(f"input path mean U95 = 2 pp at a calibration reproducibility of {100 * r2:.2f} % (both channels; "
          "from the stated terms)")
    lines = verdicts(paths[0], torque, args.quick)
    for line in lines:
        print(line)
    if args.json:
        args.json.write_text(json.dumps({"paths": paths, "torque": torque, "repro_for_2pp": r2, "seeds": seeds,
                                         "repro": args.repro, "verdicts": lines, "wall_s": wall_s}, indent=1))
    return 1 if any(line.startswith("FAIL") for line in lines) else 0


if __name__ == "__main__":
    raise SystemExit(main())
