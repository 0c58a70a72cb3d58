"""Does a point's ``efficiency_u95`` cover the truth?  Judged over many simulated rigs, in several worlds.

Each seed is a different rig (:mod:`dyno.sim.world`): its engine differs from the shipped map by a smooth
deviation, its torque sensor's gain from the latest calibration, and its day is drawn (5…35 °C,
0…1,500 m).  The host is told only what an operator would know: the shipped map (and the uncertainty the
map file states), the calibration history, and the air from a BME280.  A short speed-hold plan (4
setpoints) runs on each seed; in the worlds marked *, the same run is also re-processed with no air
("uncorrected", :func:`dyno.runlog.replay.replay` with ``Ambient()``).  The worlds (the host never changes):

* ``stated``*: the simulator's spreads set to exactly what the host states (the map file's 5 %, the
  calibration history's slope reproducibility, no thermal drift): the well-specified case, which checks
  that nothing else in the chain (J1349, the tare, the sensor, the points' statistics) adds an error;
* ``own``*: the simulator's own spreads (:mod:`dyno.sim.rig_params`: engine 4.4 %, the gauge's re-seating
  1.5 % and its thermal drift), not the host's;
* ``engine10``, ``ageing5``, ``driveline3``, ``calslope3``: the well-specified world with one error the
  host does not expect: engine deviation sd 10 %; every engine 5 % weaker (ageing); 3 % of the CVT's
  output torque lost between the CVT and the gauge; the sensor's true slope 3 % off its calibration.

Printed per world and case: points, coverage of ``efficiency_u95`` (95 % nominal), the normalised errors
``error / (u95/1.96)`` (mean, standard deviation), the mean half-width; and, for the well-specified world,
each systematic term's true contribution (RMS over seeds) beside the standard uncertainty the host states.
The systematic part is one draw per run, so coverage is also given per run (its middle point).

Pass criteria (exit 1 when one fails, 0 when all hold): coverage (points, air known) ≥ 0.90 in ``stated``
and in ``own`` (95 % nominal; 100 runs give a binomial sd of ~0.022); with ``--quick`` (4 seeds) ≥ 0.75,
a smoke check that the stated u95 is not far off.  The mis-specified worlds are reported, not judged:
they show how far coverage falls when the world is not what the host assumes.

    python bench/bench_uncertainty.py                      # 100 seeds × 6 worlds (about 25 min on 2 cores)
    python bench/bench_uncertainty.py --worlds stated,own  # those worlds only
    python bench/bench_uncertainty.py --quick              # 4 seeds, worlds stated and own
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


#: the worlds (see the module docstring): RigParams overrides on top of ``stated`` (None: the simulator's own)
MISSPECIFIED = {"engine10": {"engine_map_dev_rel_sd": 0.10}, "ageing5": {"engine_ageing_loss_frac": 0.05},
                "driveline3": {"world_driveline_loss_frac": 0.03}, "calslope3": {"world_adc_gain_shift_rel": 0.03}}
WORLDS = ("stated", "own", *MISSPECIFIED)
WITH_UNCORRECTED = ("stated", "own")
CRITERION_COVERAGE, CRITERION_COVERAGE_QUICK = 0.90, 0.75
JUDGED = ("stated", "own")


def host_stated() -> dict:
    """The spreads the host states with its shipped inputs (the map file's, else rig.toml's; the history's)."""
    from dyno.analysis.calibration import latest, load_history
    from dyno.analysis.engine_map import load_engine_map
    from dyno.analysis.systematic import calibration_rel_u
    from dyno.session.root import DEFAULT_CALIBRATION, DEFAULT_ENGINE_MAP
    from dyno.rig.config import load_rig

    emap = load_engine_map(DEFAULT_ENGINE_MAP).stated_u_rel
    if emap is None:
        emap = load_rig(REPO / "hardware" / "rig.toml").uncertainty.engine_map_rel
    history = load_history(DEFAULT_CALIBRATION)
    return {"engine_map_dev_rel_sd": emap, "adc_gain_drift_rel_sd": calibration_rel_u(history, latest(history)),
            "adc_gain_tempco_per_k": 0.0}


def world_params(name: str) -> dict:
    """RigParams overrides for world ``name`` ({} = the simulator's own)."""
    if name == "own":
        return {}
    return {**host_stated(), **MISSPECIFIED.get(name, {})}


def one_seed(seed: int, tmp: str, world: str = "own", engine_map: str | None = None) -> dict:
    """One simulated rig in ``world``: its points with the air known (and uncorrected), and its truth."""
    from dyno.analysis.air import Ambient
    from dyno.session.root import RunOptions, run_test
    from dyno.control.plans import plan_named
    from dyno.runlog.replay import replay
    from dyno.sim.rig_params import RigParams

    tmp_dir = Path(tmp)
    plan_path = tmp_dir / "short.toml"
    out = tmp_dir / f"{world}-seed{seed}"
    kw = world_params(world)
    extra = {"engine_map_path": Path(engine_map)} if engine_map else {}
    opts = RunOptions(sim=True, seed=seed, out_dir=out, rig_path=_rig_with_sensor(tmp_dir, f"rig-{world}-{seed}.toml"),
                      plan=plan_named(str(plan_path)), sim_params=RigParams(**kw), **extra)
    result = run_test(opts)
    world_rec = result["sim_world"]
    world_rec["driveline_loss_frac"] = kw.get("world_driveline_loss_frac", 0.0)
    cf_host = result["ambient"]["j1349_factor"]
    uncorrected = ([{}] * len(result["points"]) if world not in WITH_UNCORRECTED
                   else replay(out, ambient=Ambient())["points"])
    rows = []
    for p, q in zip(result["points"], uncorrected):
        if p.get("efficiency") is None or p.get("efficiency_true") is None or not p.get("valid", True):
            continue
        rows.append({"seed": seed, "rpm_primary": p["rpm_primary"], "true": p["efficiency_true"],
                     "known": (p["efficiency"], p["efficiency_u95"], p["efficiency_u95_terms"]),
                     "uncorrected": (q.get("efficiency"), q.get("efficiency_u95"), q.get("efficiency_u95_terms"))})
    return {"seed": seed, "world_name": world, "rows": rows, "world": world_rec, "cf_host": cf_host,
            "state": result["state"],
            "stated": result["points"][0]["efficiency_u95_terms"] if result["points"] else None}


def _true_parts(run: dict, rpm: float) -> dict:
    """Each systematic term's true relative contribution to (reported / true − 1) at this point."""
    import numpy as np

    w = run["world"]
    dev = float(np.interp(rpm, w["engine_dev_rpm"], w["engine_dev_rel"])) if w["engine_dev_rpm"] else 0.0
    return {"calibration": w["adc_gain_drift_rel"],
            "engine_map": (1.0 + dev) * (1.0 - w["engine_ageing_loss_frac"]) - 1.0,
            "air": run["cf_host"] / w["j1349_factor"] - 1.0}


def summarise(runs: list[dict], case: str) -> dict:
    z, covered, half = [], [], []
    per_run_cov = []
    for run in runs:
        mids = []
        for r in run["rows"]:
            eff, u95, _ = r[case]
            if eff is None or u95 is None or not u95 > 0:
                continue
            err = eff - r["true"]
            z.append(err / (u95 / 1.96))
            covered.append(abs(err) <= u95)
            half.append(u95)
            mids.append(abs(err) <= u95)
        if mids:
            per_run_cov.append(mids[len(mids) // 2])
    n = len(z)
    return {"case": case, "points": n, "runs": len(per_run_cov),
            "coverage": sum(covered) / n if n else math.nan,
            "coverage_per_run": sum(per_run_cov) / len(per_run_cov) if per_run_cov else math.nan,
            "z_mean": statistics.fmean(z) if n else math.nan, "z_sd": statistics.stdev(z) if n > 1 else math.nan,
            "mean_u95": statistics.fmean(half) if n else math.nan}


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
        eff, _, terms = r["known"]
        for k in parts:
            stated[k].append(terms[k] / 2.0 / eff)
    return [{"term": k, "true_rms": math.sqrt(statistics.fmean(v * v for v in parts[k])) if parts[k] else math.nan,
             "true_mean": statistics.fmean(parts[k]) if parts[k] else math.nan,
             "stated_u": statistics.fmean(stated[k]) if stated[k] else math.nan} for k in parts]


def _print_cases(cases: list[dict]) -> None:
    print(f"{'world':<11}{'case':<13}{'points':>7}{'runs':>6}{'coverage':>10}{'per run':>9}{'z mean':>8}"
          f"{'z sd':>7}{'mean U95 pp':>13}")
    for c in cases:
        print(f"{c['world']:<11}{c['case']:<13}{c['points']:>7}{c['runs']:>6}{c['coverage']:>10.3f}"
              f"{c['coverage_per_run']:>9.3f}{c['z_mean']:>8.2f}{c['z_sd']:>7.2f}{100 * c['mean_u95']:>13.2f}")


def verdicts(cases: list[dict], quick: bool) -> list[str]:
    """The pass criteria (module docstring): one line per judged world, 'FAIL' in it when it fails."""
    need = CRITERION_COVERAGE_QUICK if quick else CRITERION_COVERAGE
    out = []
    for c in cases:
        if c["world"] in JUDGED and c["case"] == "known":
            ok = c["coverage"] >= need  # (NaN: no points, fails)
            out.append(f"{'pass' if ok else 'FAIL'}: world {c['world']}, air known: coverage {c['coverage']:.3f} "
                       f"(criterion >= {need:.2f})")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=None, help="simulated rigs per world (default 100; --compare 50)")
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--quick", action="store_true", help="4 seeds, worlds stated and own: a smoke run")
    ap.add_argument("--worlds", default=None, help=f"comma-separated, of {', '.join(WORLDS)} (default: all; "
                    "--quick: stated,own)")
    ap.add_argument("--engine-map", default=None, metavar="CSV",
                    help="the host's engine map (default the shipped one; its '# stated_u_rel' is the map term)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    ap.add_argument("--compare", action="store_true",
                    help="the compare bench instead: pairs of runs of one rig (--seeds rigs, default 50)")
    args = ap.parse_args(argv)
    if args.compare:
        return main_compare(args)
    worlds = (args.worlds.split(",") if args.worlds else (list(JUDGED) if args.quick else list(WORLDS)))
    bad = [w for w in worlds if w not in WORLDS]
    if bad:
        print(f"bench_uncertainty: --worlds: unknown {', '.join(bad)} (expected {', '.join(WORLDS)})", file=sys.stderr)
        return 2
    if args.engine_map:
        from dyno.analysis.engine_map import load_engine_map
        from dyno.errors import ConfigError

        try:
            load_engine_map(args.engine_map)
        except ConfigError as exc:
            print(f"bench_uncertainty: --engine-map: {exc}", file=sys.stderr)
            return 2
    n = 4 if args.quick else (args.seeds or 100)
    seeds = list(range(args.first_seed, args.first_seed + n))
    jobs = [(s, w) for w in worlds for s in seeds]
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="bench-unc-") as tmp:
        (Path(tmp) / "short.toml").write_text(SHORT_PLAN)
        args_ = ([s for s, _ in jobs], [tmp] * len(jobs), [w for _, w in jobs], [args.engine_map] * len(jobs))
        if args.jobs > 1:
            with ProcessPoolExecutor(args.jobs) as pool:
                runs = list(pool.map(one_seed, *args_))
        else:
            runs = [one_seed(*a) for a in zip(*args_)]
    wall_s = time.monotonic() - t0
    by_world = {w: [r for r in runs if r["world_name"] == w] for w in worlds}
    cases = []
    for w, rs in by_world.items():
        for case in ("known", "uncorrected") if w in WITH_UNCORRECTED else ("known",):
            cases.append({"world": w, **summarise(rs, case)})
    print(f"bench_uncertainty: {len(seeds)} seeds ({seeds[0]}..{seeds[-1]}) per world, short speed-hold plan, "
          f"{sum(r['state'] == 'done' for r in runs)} of {len(runs)} runs done, {wall_s:.0f} s wall; host map "
          f"{args.engine_map or 'shipped'}")
    _print_cases(cases)
    first = "stated" if "stated" in by_world else "own" if "own" in by_world else worlds[0]
    terms = bias_by_term(by_world[first])  # (one world's runs: the worlds' errors differ)
    print(f"air known: each term's true contribution (relative, one per run) vs the host's stated standard u "
          f"(world {first})")
    print(f"{'term':<13}{'true RMS %':>11}{'true mean %':>12}{'stated u %':>11}")
    for t in terms:
        print(f"{t['term']:<13}{100 * t['true_rms']:>11.2f}{100 * t['true_mean']:>12.2f}{100 * t['stated_u']:>11.2f}")
    lines = verdicts(cases, args.quick)
    for line in lines:
        print(line)
    failed = any(line.startswith("FAIL") for line in lines)
    if args.json:
        args.json.write_text(json.dumps({"cases": cases, "terms": terms, "seeds": seeds, "worlds": worlds,
                                         "verdicts": lines, "wall_s": wall_s}, indent=1))
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
