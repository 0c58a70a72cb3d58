"""``dyno model point|sweep|study|inverse``: the belt-model library from the command line.

``dyno model point --json`` with no other argument solves the thesis's
Table 6.1 case.  Sweeps and studies write a CSV and a PNG into ``--out``.
``dyno model inverse RUN`` gives each point's geometric ratio and belt slip
(the slip-consistent inverse, :mod:`dyno.model.inverse`) at the run's tune.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path

from dyno.cli import number_in
from dyno.model.params import VARIANTS, ModelParams, OperatingPoint, TABLE_6_1, bad_input

STUDIES = ("sheave_angle", "bending_stiffness", "slack_tension", "friction")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    point = sub.add_parser("point", help="solve one operating point (default: thesis Table 6.1)")
    sweep = sub.add_parser("sweep", help="operating-range sweep by continuation")
    study = sub.add_parser("study", help="thesis Section 7 parameter study")
    inverse = sub.add_parser("inverse", help="geometric ratio and belt slip of each point of a run")
    overlay = sub.add_parser("overlay", help="the belt model's prediction at each point of a run, with its balances")
    overlay.add_argument("run_dir", type=Path, metavar="RUN", help="run directory (its tune.toml sets the clamp)")
    overlay.add_argument("--tune", type=Path, default=None, help="tune TOML instead of RUN/tune.toml")
    overlay.add_argument("--tier", choices=("closed_form", "full"), default="full",
                         help="model tier (full: the BVP, seconds per point; closed_form: the creep-only bound)")
    overlay.add_argument("--json", action="store_true", help="print JSON instead of text")
    inverse.add_argument("run_dir", type=Path, metavar="RUN", help="run directory (its tune.toml sets the clamp)")
    inverse.add_argument("--tune", type=Path, default=None, help="tune TOML instead of RUN/tune.toml")
    inverse.add_argument("--tier", choices=("closed_form", "full"), default="closed_form",
                         help="slip tier (full: the BVP, seconds per point)")
    inverse.add_argument("--json", action="store_true", help="print JSON instead of text")
    study.add_argument("name", choices=STUDIES, help="the parameter varied (thesis Section 7)")
    study.add_argument("--values", type=number_in(-1e12, 1e12), nargs="+", help="parameter values (default: the thesis's)")
    for p in (point, sweep, study):
        p.add_argument("--variant", choices=VARIANTS, default="corrected",
                       help="corrected (default), or as_published: the equations as the thesis prints them (a warning says its "
                            "efficiency is mostly an artefact; docs/belt-model.md)")
        p.add_argument("--json", action="store_true", help="print JSON instead of text")
        p.add_argument("--tier", choices=("full", "closed_form", "capstan"), default="full",
                       help="model tier (full: the BVP; closed_form: the creep-only bound; capstan: the capstan thrust)")
        p.add_argument("--slip-threshold", type=number_in(0.0, 1.0, lo_open=True), default=1e-4, metavar="M_S", help="adhesion slip speed [m/s]")
        p.add_argument("--tol", type=number_in(0.0, 1.0, lo_open=True), default=1e-3, help="solve_bvp tolerance")
        p.add_argument("--rpm", type=number_in(0.0, 20000.0, lo_open=True), default=3400.0, help="primary speed [rpm]")
        p.add_argument("--torque", type=number_in(0.0, 500.0, lo_open=True), default=18.0, help="primary torque [N*m]")
        p.add_argument("--slack-tension", type=number_in(0.0, 1e5, lo_open=True), default=None, help="slack-span tractive tension [N] (default 100)")
        p.add_argument("--axial-force", type=number_in(0.0, 1e6, lo_open=True), default=None, help="primary axial force [N] instead of slack tension")
        p.add_argument("--bending-stiffness", type=number_in(0.0, 100.0, lo_open=True), default=None, help="EI [N*m^2]")
        p.add_argument("--sheave-angle", type=number_in(1.0, 45.0), default=None, help="sheave half-angle [deg] (k scaled by tan)")
        p.add_argument("--friction", type=number_in(0.0, 2.0, lo_open=True), default=None, help="kinetic friction coefficient")
    point.add_argument("--ratio", type=number_in(0.1, 10.0), default=1.0, help="geometric ratio R_S/R_P")
    point.add_argument("--profiles", type=Path, default=None, help="write the profiles to this CSV")
    for p in (sweep, study):
        p.add_argument("--points", type=number_in(2, 1000, integer=True), default=20, help="ratios between --ratio-range ends")
        p.add_argument("--ratio-range", type=number_in(0.1, 10.0), nargs=2, default=(1.74, 0.72), metavar=("LOW", "HIGH"),
                       help="geometric ratios R_S/R_P at the two ends (default 1.74 0.72)")
        p.add_argument("--out", type=Path, default=Path("model-out"), help="directory for CSV, Parquet and PNG")
        p.add_argument("--jobs", type=number_in(1, 1024, integer=True), default=None,
                       help="local worker processes (default: the machine's cores; 1: this process)")
        p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                       help="a dask.distributed scheduler (tcp://HOST:8786): solve on its workers (extra [cluster])")
        p.add_argument("--no-cache", action="store_true",
                       help="solve every task again (default: reuse the solution cache, $DYNO_MODEL_CACHE/studies)")


def _params(args) -> ModelParams:
    params = TABLE_6_1
    if args.sheave_angle is not None:
        params = params.with_sheave_angle(args.sheave_angle)
    changes = {}
    if args.bending_stiffness is not None:
        changes["bending_stiffness_nm2"] = args.bending_stiffness
    if args.friction is not None:
        changes["friction_coefficient"] = args.friction
    return params.with_belt(**changes) if changes else params


def _op(args, ratio: float = 1.0) -> OperatingPoint:
    if args.slack_tension is not None and args.axial_force is not None:
        raise bad_input("--slack-tension/--axial-force", "only one of the two")
    slack = None if args.axial_force is not None else (100.0 if args.slack_tension is None else args.slack_tension)
    return OperatingPoint(ratio=ratio, primary_speed_rpm=args.rpm, primary_torque_nm=args.torque,
                          slack_tension_n=slack, primary_axial_force_n=args.axial_force)


def _check_numbers(args) -> None:
    if not (math.isfinite(args.slip_threshold) and args.slip_threshold > 0):
        raise bad_input("--slip-threshold", "a positive speed in m/s")
    if not (1e-8 <= args.tol <= 0.1):
        raise bad_input("--tol", "between 1e-8 and 0.1")


def _fast_summary(tier, params, op) -> dict:
    if tier == "closed_form":
        from dyno.model.closed_form import closed_form_point as fn
    else:
        from dyno.model.capstan import capstan_point as fn
    r = fn(params, op)
    return {
        "tier": tier,
        "converged": True,
        "wrap_deg": {"primary": math.degrees(r.wrap_primary_rad), "secondary": math.degrees(r.wrap_secondary_rad)},
        "axial_force_n": {"primary": r.axial_force_primary_n, "secondary": r.axial_force_secondary_n},
        "efficiency": {"speed": r.efficiency_speed, "torque": r.efficiency_torque, "overall": r.efficiency_overall},
        "span_tension_n": {"tight": r.tight_tension_n, "slack": r.slack_tension_n},
    }


def _print(summary: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(summary, indent=2, default=float))
        return
    for key, value in summary.items():
        if isinstance(value, dict):
            inner = ", ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in value.items())
            print(f"{key}: {inner}")
        else:
            print(f"{key}: {value:.6g}" if isinstance(value, float) else f"{key}: {value}")


def _run_point(args) -> int:
    params, op = _params(args), _op(args, args.ratio)
    if args.tier != "full":
        summary = _fast_summary(args.tier, params, op)
        summary["variant"] = args.variant
        _print(summary, args.json)
        return 0
    from dyno.model.solution import solve_point

    from dyno.errors import GrossSlip

    try:
        sol = solve_point(params, op, variant=args.variant, slip_threshold_m_s=args.slip_threshold, tol=args.tol)
    except GrossSlip as exc:
        # A physical answer, not a numerical failure: say it as a state (exit 1: no steady point).
        _print({"state": "gross_slip", "converged": False, "variant": args.variant, "reason": str(exc)}, args.json)
        return 1
    if args.profiles is not None:
        _write_profiles(sol.profiles(), args.profiles)
    _print(sol.as_dict(), args.json)
    return 0


def _write_profiles(profiles: dict, path: Path) -> None:
    import csv

    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["region", "quantity", "values..."])
        for region, cols in profiles.items():
            for name, values in cols.items():
                w.writerow([region, name, *(f"{v:.9g}" for v in values)])


def _save(out: Path, stem: str, csv_text: str, fig) -> list[str]:
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.csv").write_text(csv_text)
    fig.savefig(out / f"{stem}.png", dpi=110)
    return [str(out / f"{stem}.csv"), str(out / f"{stem}.png")]


def _executor(args):
    from dyno.model.executor import make_executor

    return make_executor(args.jobs, args.scheduler)


def _say_start(args, what: str, ex) -> None:
    if not args.json:
        print(f"dyno model {args.action}: {what} on {ex.name}", file=sys.stderr, flush=True)


def _progress(args):
    """A progress line on a terminal (stderr), one line per task through a pipe; nothing with --json."""
    if args.json:
        return None
    tty = sys.stderr.isatty()

    def show(done, total, label, cached):
        bar = "#" * round(20 * done / total)
        text = f"[{bar:<20}] {done}/{total} {label} ({'cached' if cached else 'solved'})"
        print(("\r" + text.ljust(78)) if tty else text, end="" if tty and done < total else "\n",
              file=sys.stderr, flush=True)

    return show


def _save_parquet(out: Path, stem: str, rows_by_label: dict, column: str | None) -> list[str]:
    """The rows as Parquet too when pyarrow is installed (extra [export]); otherwise the CSV alone."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return []
    from dyno.model.sweep import CSV_COLUMNS

    cols = ([column] if column else []) + list(CSV_COLUMNS)
    flat = [{**({column: label} if column else {}), **row} for label, rows in rows_by_label.items() for row in rows]
    pq.write_table(pa.table({c: [r.get(c) for r in flat] for c in cols}), out / f"{stem}.parquet")
    return [str(out / f"{stem}.parquet")]


def _run_sweep(args) -> int:
    from dyno.model import studies, sweep

    with _executor(args) as ex:
        _say_start(args, f"{args.points} ratios in 2 tasks (one per side of 1:1)", ex)
        rows, counts = studies.run_sweep(args.points, _params(args), _op(args), ratio_range=tuple(args.ratio_range),
                                         variant=args.variant, slip_threshold_m_s=args.slip_threshold, tol=args.tol,
                                         executor=ex, use_cache=not args.no_cache, progress=_progress(args))
    stem = f"sweep-{args.variant}"
    files = _save(args.out, stem, sweep.rows_to_csv(rows), sweep.plot_sweep({args.variant: rows}, "operating-range sweep"))
    files += _save_parquet(args.out, stem, {args.variant: rows}, None)
    n_ok = sum(bool(r["converged"]) for r in rows)
    result = {"variant": args.variant, "points": len(rows), "converged": n_ok, "files": files,
              "executor": ex.name, "tasks": counts, "rows": rows if args.json else None}
    _print({k: v for k, v in result.items() if v is not None}, args.json)
    return 0 if n_ok == len(rows) else 1


def _run_study(args) -> int:
    from dyno.model import studies, sweep

    with _executor(args) as ex:
        n_values = len(args.values) if args.values else len(studies.DEFAULT_VALUES[args.name])
        _say_start(args, f"{args.name}: {n_values} values x {args.points} ratios, one task per value", ex)
        result = studies.run_study(args.name, values=args.values, base_params=_params(args), op=_op(args),
                                   n_points=args.points, ratio_range=tuple(args.ratio_range), variant=args.variant,
                                   slip_threshold_m_s=args.slip_threshold, tol=args.tol, executor=ex,
                                   use_cache=not args.no_cache, progress=_progress(args))
    stem = f"study-{args.name}-{args.variant}"
    files = _save(args.out, stem, studies.study_csv(result),
                  sweep.plot_sweep({f"{args.name}={v:g}": rows for v, rows in result["series"].items()},
                                   f"parameter study: {args.name}"))
    files += _save_parquet(args.out, stem, result["series"], args.name)
    n_ok = sum(bool(r["converged"]) for rows in result["series"].values() for r in rows)
    n_all = sum(len(rows) for rows in result["series"].values())
    _print({"study": args.name, "variant": args.variant, "points": n_all, "converged": n_ok, "files": files,
            "executor": ex.name, "tasks": result["tasks"]}, args.json)
    return 0 if n_ok == n_all else 1


def _run_inverse(args) -> int:
    from dyno.model.inverse import invert_points
    from dyno.runlog.reader import load_run
    from dyno.tuning.tune import load_tune

    run = load_run(args.run_dir, with_events=False)
    tune_path = args.tune if args.tune is not None else args.run_dir / "tune.toml"
    tune = load_tune(tune_path) if args.tune is not None or tune_path.is_file() else None
    points = [p for p in run.points if p.get("valid", True)]
    rows = []
    for p, (_, res) in zip(points, invert_points(points, tune, tier=args.tier)):
        row = {"index": p.get("index"), "rpm_primary": p["rpm_primary"], "speed_ratio": res.speed_ratio,
               "geometric_ratio": res.geometric_ratio, "slip": res.slip,
               "primary_axial_force_n": res.primary_axial_force_n, "primary_torque_nm": res.primary_torque_nm,
               "state": res.state, "tier": res.tier}
        if res.reason:
            row["reason"] = res.reason
        for k in ("ratio_geometric_true", "belt_slip_true"):  # a simulated run's truth
            if k in p:
                row[k] = p[k]
        rows.append(row)
    level = f"tune {tune.name!r}" if tune is not None else "no tune: Table 6.1 drive at 100 N slack"
    if args.json:
        print(json.dumps({"run": str(args.run_dir), "clamp": level, "tier": args.tier, "points": rows},
                         default=float))
    else:
        print(f"{args.run_dir}: {len(rows)} points, clamp from {level}, slip tier {args.tier}")
        print("  #   rpm_p  speed_ratio  geometric  slip %   clamp N  state")
        for r in rows:
            print(f"{r['index'] if r['index'] is not None else '':>3} {r['rpm_primary']:7.0f} {r['speed_ratio']:12.5f} "
                  f"{r['geometric_ratio']:10.5f} {100 * r['slip']:7.3f} {r['primary_axial_force_n']:9.0f}  "
                  f"{r['state']}{'  ' + r['reason'][:80] if 'reason' in r else ''}")
    return 0


def run(args) -> int:
    if args.action == "inverse":
        return _run_inverse(args)
    if args.action == "overlay":
        from dyno.cli.model_overlay_cmd import run_overlay

        return run_overlay(args)
    _check_numbers(args)
    if args.action == "point":
        return _run_point(args)
    if args.action == "sweep":
        return _run_sweep(args)
    return _run_study(args)
