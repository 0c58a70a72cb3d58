"""Does a point's ``efficiency_interval95`` hold the truth?  Judged over many simulated rigs, in worlds the
host does and does not expect, on both paths: the engine map's and the input torque channel's.

Each seed is a different rig (:mod:`dyno.sim.world`): its engine differs from the shipped map by a smooth
deviation, its torque sensor's gain from the latest calibration, and its day is drawn (5…35 °C,
0…1,500 m).  The host is told only what an operator would know: the shipped map (and the uncertainty the
map file states), the calibration histories, the air from a BME280 and the rig file's ``[driveline]`` bound.
A short speed-hold plan (4 setpoints) runs on each seed, on each path:

* ``map``: the thesis rig (``hardware/rig.toml``): the efficiency divides by the engine map's power;
* ``input``: the input-torque rig (``hardware/rig-input-torque.toml`` with a BME280 and the thesis rig's
  ``[driveline]``): the efficiency divides by the measured engine power.

The worlds (the host never changes; RigParams overrides on the ``stated`` world; docs/analysis.md lists what
each of the host's statements does not describe):

* ``stated``: the simulator's spreads set to exactly what the host states (the map file's 5 %, the
  calibration history's slope reproducibility, no thermal drift);
* ``own``: the simulator's own spreads and effects (:mod:`dyno.sim.rig_params`);
* ``engine10``: engine deviation sd 10 %; ``ageing8``: every engine 8 % weaker than its map;
* ``gauge3``: the gauge's slope drifting within the run as the brake warms the shaft, 6e-4 per K of the
  rotor above the day: 3 % at a 50 K rise, about where a short run's last points are (the simulated rotor
  gains ~1.1 K/s at 4 kW);
* ``driveline3``: the driveline at the host's whole bound, 3 % of the load + 0.25 N·m, with the simulator's
  speed-dependent drag (0.005 N·m per 1000 rpm) on top;
* ``air2``: the air sensor reading 2 °C warm;
* reported, not judged: ``ageing5``, ``calslope3`` (the gauge's true slope 3 % off its calibration).

The systematic part is one draw per run, so coverage counts runs, not points: a run is covered when its
middle point's interval holds the truth.  Printed per world and path: runs, the coverage (point estimate)
with its Wilson 95 % interval, the points' coverage, the mean interval width and the mean ``efficiency_u95``
(half the width: the same statement).  In ``stated`` and ``own`` on the map path the same runs are also
re-processed with no air ("uncorrected", :func:`dyno.runlog.replay.replay` with ``Ambient()``), reported.

Pass criteria (exit 1 when one fails, 0 when all hold), in every judged world on each path run: coverage not
significantly below 0.90 (it fails when the Wilson 95 % upper bound is under 0.90; 60 seeds by default), and
the mean width within its cap: ≤ 40 pp on the map path (against inflation), ≤ 10 pp on the input path.
``--quick`` (4 seeds, worlds ``stated`` and ``own``, both paths): looser bounds, a smoke check that the interval
is not far off: the Wilson upper bound must reach 0.75, and the mean width stay within 1.2 × its cap (48 / 12
pp: four runs' mean width scatters, and the input path's sits at its cap while its driveline is bounded, not
measured).

    python bench/bench_uncertainty.py                          # 60 seeds x 7 worlds x 2 paths
    python bench/bench_uncertainty.py --worlds stated,own      # those worlds only
    python bench/bench_uncertainty.py --paths map              # the map path only
    python bench/bench_uncertainty.py --quick                  # 4 seeds, worlds stated and own
    python bench/bench_uncertainty.py --quick --engine-map FILE   # the host given another map (or its stated u)

``--compare``: instead, ``dyno compare``'s difference uncertainty on pairs of runs of one rig
(:mod:`bench_compare_cancel`: stock vs heavy flyweights, same and different days, air known or not).

    python bench/bench_uncertainty.py --compare           # 50 rigs: 100 runs, 150 pairs (about 10 min)
    python bench/bench_uncertainty.py --compare --quick   # 2 rigs
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

SHORT_PLAN = """schema = "dyno.plan/1"
name = "speed-hold-short"
description = "four speed-hold setpoints (bench_uncertainty)"
mode = "speed-hold"
[test]
warmup_s = 3.0
warmup_at_load_s = 5.0
measure_s = 2.5
target_efficiency_ci95 = 0.009
max_measure_s = 10.0
min_point_torque_nm = 4.0
target_points = 4
[speed_hold]
points = 4
low_rpm = 2200.0
"""


def _rig_with_sensor(tmp: Path, name: str = "rig-bme280.toml") -> Path:
    """The shipped rig file with the BME280 fitted (one file per run: parallel workers never share one)."""
    text = (REPO / "hardware" / "rig.toml").read_text().replace('sensor = "none"', 'sensor = "bme280"', 1)
    path = tmp / name
    path.write_text(text)
    return path


def _input_rig(tmp: Path, name: str) -> Path:
    """The input-torque rig with a BME280 and the thesis rig's ``[driveline]`` bound (its gauge is still after
    the chain, so the same loss lowers its P_out)."""
    thesis = (REPO / "hardware" / "rig.toml").read_text()
    driveline = thesis[thesis.index("[driveline]"):].split("\n[", 1)[0]
    text = (REPO / "hardware" / "rig-input-torque.toml").read_text().replace('sensor = "none"', 'sensor = "bme280"', 1)
    path = tmp / name
    path.write_text(text.rstrip("\n") + "\n\n" + driveline.rstrip("\n") + "\n")
    return path


#: the worlds (see the module docstring): RigParams overrides on top of ``stated`` (None: the simulator's own)
MISSPECIFIED = {"engine10": {"engine_map_dev_rel_sd": 0.10}, "ageing8": {"engine_ageing_loss_frac": 0.08},
                "gauge3": {"adc_gain_rotor_tempco_per_k": 6e-4},
                "driveline3": {"driveline_loss_load_frac": 0.03, "driveline_loss_drag_nm": 0.25},
                "air2": {"bme280_temp_bias_c": 2.0},
                "ageing5": {"engine_ageing_loss_frac": 0.05}, "calslope3": {"world_adc_gain_shift_rel": 0.03}}
WORLDS = ("stated", "own", *MISSPECIFIED)
JUDGED = ("stated", "own", "engine10", "ageing8", "gauge3", "driveline3", "air2")
QUICK_WORLDS = ("stated", "own")
PATHS = ("map", "input")
WITH_UNCORRECTED = ("stated", "own")  # (the map path's)
CRITERION_COVERAGE, CRITERION_COVERAGE_QUICK = 0.90, 0.75
WIDTH_CAP_PP = {"map": 40.0, "input": 10.0}
WIDTH_CAP_QUICK_FACTOR = 1.2
DEFAULT_SEEDS = 60


def host_stated() -> dict:
    """The spreads the host states with its shipped inputs (the map file's, else rig.toml's; the history's)."""
    from dyno.analysis.calibration_history import latest, load_history
    from dyno.analysis.engine_map import load_engine_map
    from dyno.analysis.systematic import calibration_rel_u
    from dyno.resources import DEFAULT_CALIBRATION, DEFAULT_ENGINE_MAP
    from dyno.rig.config import load_rig

    emap = load_engine_map(DEFAULT_ENGINE_MAP).stated_u_rel
    if emap is None:
        emap = load_rig(REPO / "hardware" / "rig.toml").uncertainty.engine_map_rel
    history = load_history(DEFAULT_CALIBRATION)
    inputs = load_history(REPO / "calibration" / "input_torque_calibration.csv")  # (the input rig's channel)
    return {"engine_map_dev_rel_sd": emap, "adc_gain_drift_rel_sd": calibration_rel_u(history, latest(history)),
            "adc_gain_tempco_per_k": 0.0, "input_gain_drift_rel_sd": calibration_rel_u(inputs, latest(inputs))}


def world_params(name: str) -> dict:
    """RigParams overrides for world ``name`` ({} = the simulator's own)."""
    if name == "own":
        return {}
    return {**host_stated(), **MISSPECIFIED.get(name, {})}


def _interval_row(p: dict) -> tuple:
    """(efficiency, its interval95, its u95) of a public point; Nones where absent."""
    return p.get("efficiency"), p.get("efficiency_interval95"), p.get("efficiency_u95")


def one_seed(seed: int, tmp: str, world: str = "own", engine_map: str | None = None, path: str = "map") -> dict:
    """One simulated rig in ``world`` on ``path``: its points (air known, and uncorrected), and its truth."""
    from dyno.analysis.air import Ambient
    from dyno.session.root import RunSpec, run_test
    from dyno.control.plans import plan_named
    from dyno.runlog.replay import replay
    from dyno.sim.rig_params import RigParams

    tmp_dir = Path(tmp)
    plan_path = tmp_dir / "short.toml"
    out = tmp_dir / f"{path}-{world}-seed{seed}"
    kw = world_params(world)
    extra = {"engine_map_path": Path(engine_map)} if engine_map else {}
    rig = (_input_rig if path == "input" else _rig_with_sensor)(tmp_dir, f"rig-{path}-{world}-{seed}.toml")
    opts = RunSpec(sim=True, seed=seed, out_dir=out, rig_path=rig, plan=plan_named(str(plan_path)),
                      sim_params=RigParams(**kw), **extra)
    result = run_test(opts)
    world_rec = result["sim_world"]
    cf_host = result["ambient"]["j1349_factor"]
    uncorrected = (replay(out, ambient=Ambient())["points"] if path == "map" and world in WITH_UNCORRECTED
                   else [{}] * len(result["points"]))
    rows = []
    for p, q in zip(result["points"], uncorrected):
        if p.get("efficiency") is None or p.get("efficiency_true") is None or not p.get("valid", True):
            continue
        rows.append({"seed": seed, "rpm_primary": p["rpm_primary"], "true": p["efficiency_true"],
                     "known": _interval_row(p), "uncorrected": _interval_row(q),
                     "terms": p.get("efficiency_u95_terms")})
    return {"seed": seed, "world_name": world, "path": path, "rows": rows, "world": world_rec, "cf_host": cf_host,
            "state": result["state"]}


def wilson95(k: int, n: int) -> tuple[float, float]:
    """The Wilson score 95 % interval of a proportion k/n ((nan, nan) without a trial)."""
    if n <= 0:
        return math.nan, math.nan
    z = 1.959964
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def _covers(row: dict, case: str) -> bool | None:
    eff, iv, _ = row[case]
    if eff is None or not iv or None in iv:
        return None
    return iv[0] <= row["true"] <= iv[1]


def summarise(runs: list[dict], case: str) -> dict:
    """Coverage of the interval: per run (its middle point), with the Wilson interval, and per point; widths."""
    points, widths, u95s, per_run = [], [], [], []
    for run in runs:
        mids = []
        for r in run["rows"]:
            c = _covers(r, case)
            if c is None:
                continue
            iv, u95 = r[case][1], r[case][2]
            points.append(c)
            widths.append(iv[1] - iv[0])
            if isinstance(u95, (int, float)):
                u95s.append(u95)
            mids.append(c)
        if mids:
            per_run.append(mids[len(mids) // 2])
    k, n = sum(per_run), len(per_run)
    lo, hi = wilson95(k, n)
    return {"case": case, "runs": n, "covered_runs": k, "coverage": k / n if n else math.nan, "wilson_low": lo,
            "wilson_high": hi, "points": len(points), "coverage_points": sum(points) / len(points) if points else math.nan,
            "mean_width_pp": 100 * statistics.fmean(widths) if widths else math.nan,
            "mean_u95_pp": 100 * statistics.fmean(u95s) if u95s else math.nan}


def _true_parts(run: dict, rpm: float) -> dict:
    """Each systematic term's true relative contribution to (reported / true − 1) at this point."""
    import numpy as np

    w = run["world"]
    dev = float(np.interp(rpm, w["engine_dev_rpm"], w["engine_dev_rel"])) if w["engine_dev_rpm"] else 0.0
    return {"calibration": w["adc_gain_drift_rel"],
            "engine_map": (1.0 + dev) * (1.0 - w["engine_ageing_loss_frac"]) - 1.0,
            "air": run["cf_host"] / w["j1349_factor"] - 1.0}


def bias_by_term(runs: list[dict]) -> list[dict]:
    """RMS and mean of each term's true contribution (one value per run, at its middle point), against
    the standard relative uncertainty the host states (its 95 % half-width / 2 / efficiency)."""
    parts: dict = {"calibration": [], "engine_map": [], "air": []}
    stated: dict = {k: [] for k in parts}
    for run in runs:
        if not run["rows"]:
            continue
        r = run["rows"][len(run["rows"]) // 2]
        for k, v in _true_parts(run, r["rpm_primary"]).items():
            parts[k].append(v)
        eff, terms = r["known"][0], r["terms"] or {}
        for k in parts:
            stated[k].append(terms.get(k, math.nan) / 2.0 / eff)
    return [{"term": k, "true_rms": math.sqrt(statistics.fmean(v * v for v in parts[k])) if parts[k] else math.nan,
             "true_mean": statistics.fmean(parts[k]) if parts[k] else math.nan,
             "stated_u": statistics.fmean(stated[k]) if stated[k] else math.nan} for k in parts]


def _print_cases(cases: list[dict]) -> None:
    print(f"{'world':<11}{'path':<6}{'case':<12}{'runs':>5}{'coverage':>9}{'Wilson 95 %':>14}{'points':>7}"
          f"{'pt cov':>7}{'width pp':>9}{'U95 pp':>8}")
    for c in cases:
        print(f"{c['world']:<11}{c['path']:<6}{c['case']:<12}{c['runs']:>5}{c['coverage']:>9.3f}"
              f"{c['wilson_low']:>7.3f}-{c['wilson_high']:.3f}{c['points']:>7}{c['coverage_points']:>7.3f}"
              f"{c['mean_width_pp']:>9.1f}{c['mean_u95_pp']:>8.2f}")


def verdicts(cases: list[dict], quick: bool) -> list[str]:
    """The pass criteria (module docstring): two lines per judged world and path, 'FAIL' in one that fails."""
    need = CRITERION_COVERAGE_QUICK if quick else CRITERION_COVERAGE
    out = []
    for c in cases:
        if c["world"] not in JUDGED or c["case"] != "known":
            continue
        where = f"world {c['world']}, path {c['path']}"
        ok = c["wilson_high"] >= need  # (NaN: no run judged, fails)
        out.append(f"{'pass' if ok else 'FAIL'}: {where}: coverage {c['coverage']:.3f} of {c['runs']} runs "
                   f"(Wilson 95 % upper bound {c['wilson_high']:.3f}, criterion >= {need:.2f})")
        cap = WIDTH_CAP_PP[c["path"]] * (WIDTH_CAP_QUICK_FACTOR if quick else 1.0)
        ok = c["mean_width_pp"] <= cap
        out.append(f"{'pass' if ok else 'FAIL'}: {where}: mean width {c['mean_width_pp']:.1f} pp (cap {cap:.0f} pp)")
    return out


def _parse_list(text: str | None, allowed, default, what: str):
    items = text.split(",") if text else list(default)
    bad = [w for w in items if w not in allowed]
    if bad:
        print(f"bench_uncertainty: --{what}: unknown {', '.join(bad)} (expected {', '.join(allowed)})", file=sys.stderr)
        return None
    return items


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=None,
                    help=f"simulated rigs per world and path (default {DEFAULT_SEEDS}; --compare 50)")
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--quick", action="store_true", help="4 seeds, worlds stated and own, both paths: a smoke run")
    ap.add_argument("--worlds", default=None, help=f"comma-separated, of {', '.join(WORLDS)} (default: the judged "
                    f"{', '.join(JUDGED)}; --quick: {','.join(QUICK_WORLDS)})")
    ap.add_argument("--paths", default=None, help="comma-separated, of map, input (default both)")
    ap.add_argument("--engine-map", default=None, metavar="CSV",
                    help="the host's engine map (default the shipped one; its '# stated_u_rel' is the map term)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    ap.add_argument("--compare", action="store_true",
                    help="the compare bench instead: pairs of runs of one rig (--seeds rigs, default 50)")
    args = ap.parse_args(argv)
    if args.compare:
        return main_compare(args)
    worlds = _parse_list(args.worlds, WORLDS, QUICK_WORLDS if args.quick else JUDGED, "worlds")
    paths = _parse_list(args.paths, PATHS, PATHS, "paths")
    if worlds is None or paths is None:
        return 2
    if args.engine_map:
        from dyno.analysis.engine_map import load_engine_map
        from dyno.errors import ConfigError

        try:
            load_engine_map(args.engine_map)
        except ConfigError as exc:
            print(f"bench_uncertainty: --engine-map: {exc}", file=sys.stderr)
            return 2
    n = 4 if args.quick else (args.seeds or DEFAULT_SEEDS)
    seeds = list(range(args.first_seed, args.first_seed + n))
    jobs = [(s, w, pa) for pa in paths for w in worlds for s in seeds]
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="bench-unc-") as tmp:
        (Path(tmp) / "short.toml").write_text(SHORT_PLAN)
        args_ = ([s for s, _, _ in jobs], [tmp] * len(jobs), [w for _, w, _ in jobs], [args.engine_map] * len(jobs),
                 [pa for _, _, pa in jobs])
        if args.jobs > 1:
            with ProcessPoolExecutor(args.jobs) as pool:
                runs = list(pool.map(one_seed, *args_))
        else:
            runs = [one_seed(*a) for a in zip(*args_)]
    wall_s = time.monotonic() - t0
    cases = []
    for pa in paths:
        for w in worlds:
            rs = [r for r in runs if r["world_name"] == w and r["path"] == pa]
            for case in ("known", "uncorrected") if pa == "map" and w in WITH_UNCORRECTED else ("known",):
                cases.append({"world": w, "path": pa, **summarise(rs, case)})
    print(f"bench_uncertainty: {len(seeds)} seeds ({seeds[0]}..{seeds[-1]}) per world and path, short speed-hold "
          f"plan, {sum(r['state'] == 'done' for r in runs)} of {len(runs)} runs done, {wall_s:.0f} s wall; host map "
          f"{args.engine_map or 'shipped'}; coverage of efficiency_interval95, per run (its middle point)")
    _print_cases(cases)
    terms = []
    if "map" in paths:
        first = "stated" if "stated" in worlds else worlds[0]
        terms = bias_by_term([r for r in runs if r["world_name"] == first and r["path"] == "map"])
        print(f"map path, air known: each term's true contribution (relative, one per run) vs the host's stated "
              f"standard u (world {first})")
        print(f"{'term':<13}{'true RMS %':>11}{'true mean %':>12}{'stated u %':>11}")
        for t in terms:
            print(f"{t['term']:<13}{100 * t['true_rms']:>11.2f}{100 * t['true_mean']:>12.2f}{100 * t['stated_u']:>11.2f}")
    lines = verdicts(cases, args.quick)
    for line in lines:
        print(line)
    failed = any(line.startswith("FAIL") for line in lines)
    if args.json:
        args.json.write_text(json.dumps({"cases": cases, "terms": terms, "seeds": seeds, "worlds": worlds,
                                         "paths": paths, "verdicts": lines, "wall_s": wall_s}, indent=1))
    return 1 if failed else 0


def main_compare(args) -> int:
    """The compare bench (bench_compare_cancel): coverage of U_d over pairs of runs of one rig."""
    import bench_compare_cancel as bc

    n = 2 if args.quick else (args.seeds or 50)
    worlds = list(range(args.first_seed, args.first_seed + n))
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="bench-cmp-") as tmp:
        plan = Path(tmp) / "short.toml"
        plan.write_text(SHORT_PLAN)
        results = bc.run(worlds, args.jobs, tmp, str(_rig_with_sensor(Path(tmp))), str(plan))
    rows = bc.summarise(results)
    print(f"bench_uncertainty --compare: {n} rigs ({worlds[0]}..{worlds[-1]}), stock vs heavy flyweights, "
          f"short speed-hold plan, {time.monotonic() - t0:.0f} s wall")
    bc.print_table(rows)
    for w in results:  # a pair compare refused (e.g. no common speed range) or without a truth to judge
        for p in w["pairs"]:
            if not p.get("rows"):
                print(f"  rig {w['world']} {p['case']}: not judged ({p.get('error', 'no grid point with a truth')})")
    if args.json:
        args.json.write_text(json.dumps({"compare": rows, "worlds": worlds}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
