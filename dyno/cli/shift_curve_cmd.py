"""``dyno shift-curve``: predicted steady shift curve for a tune."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from dyno.cli import number_in

from dyno.resources import resource


def add_arguments(parser) -> None:
    parser.add_argument("tune", metavar="TUNE", help="tune TOML (see calibration/tunes/)")
    parser.add_argument("--engine-map", metavar="CSV",
                        help="engine map: rpm + torque_nm / power_kw / hp (default: the first "
                             "calibration/engine_maps/*.csv)")
    parser.add_argument("--run", metavar="RUN", help="overlay a logged run directory's steady points")
    parser.add_argument("--fit", metavar="RUN", nargs="+",
                        help="fit belt friction, flyweight radius offset and secondary friction torque to "
                             "logged runs (each with its tune.toml, else TUNE; its engine_map.csv), then "
                             "predict TUNE's curve with the fitted values")
    parser.add_argument("--points", type=number_in(2, 10_000, integer=True), default=50, help="load points along the shift (default 50)")
    parser.add_argument("--phase", choices=("steady", "upshift", "downshift"), default="steady",
                        help="helix torque split of Sorge eq. 11 (default steady: equal split)")
    parser.add_argument("--no-sensitivity", action="store_true", help="skip the sensitivity table")
    parser.add_argument("--json", action="store_true", help="print the curve as JSON")
    parser.add_argument("--png", metavar="FILE", help="save engine rpm and efficiency vs secondary rpm")


def default_engine_map() -> Path | None:
    maps = sorted(resource("calibration/engine_maps").glob("*.csv"))
    if maps:
        return maps[0]
    from dyno.datapaths import legacy_data_dir

    thesis_map = legacy_data_dir() / "engine_power_RPM.csv"
    return thesis_map if thesis_map.exists() else None


def measured_points(run_dir) -> list[dict]:
    """Steady points of a logged run: engine rpm, secondary rpm, torque, efficiency."""
    from dyno.runlog.reader import load_run

    run = load_run(run_dir)
    out = []
    for p in run.points:
        rp, rs = p.get("rpm_primary", math.nan), p.get("rpm_secondary", math.nan)
        if p.get("valid", True) and rp == rp and rs == rs and rs > 0:
            out.append({"engine_rpm": rp, "secondary_rpm": rs,
                        "torque_secondary_nm": p.get("torque_secondary_nm", math.nan),
                        "efficiency": p.get("efficiency", math.nan)})
    return out


def run(args) -> int:
    from dyno.errors import ConfigError
    from dyno.tuning.shift_curve import compare_to_measured, load_engine_map, predict_shift_curve, sensitivities
    from dyno.tuning.tune import load_tune

    tune = load_tune(args.tune)
    # One engine map on both sides: the fit uses each run's stored map, so the curve and the comparison
    # with --run use the run's (or the first fitted run's) stored map too unless --engine-map says otherwise
    # (the default calibration/engine_maps/*.csv is the part-throttle file: another prediction altogether).
    map_path = args.engine_map
    for run_dir in ([args.run] if args.run else []) + list(args.fit or []):
        if map_path is None and (Path(run_dir) / "engine_map.csv").exists():
            map_path = Path(run_dir) / "engine_map.csv"
    map_path = map_path or default_engine_map()
    if map_path is None:
        raise ConfigError("<engine map>", "--engine-map", "an engine map CSV (none found in calibration/engine_maps)")
    engine = load_engine_map(map_path)
    closing = {"steady": None, "upshift": False, "downshift": True}[args.phase]
    fit = None
    params, solver_kw = None, {}
    from dyno.tuning.fit import NOMINAL, fit_runs, load_fit_run, residual_summary, solver_for

    theta = list(NOMINAL)
    if args.fit:
        runs = []
        for run_dir in args.fit:
            has_tune = (Path(run_dir) / "tune.toml").exists()
            runs.append(load_fit_run(run_dir, tune=None if has_tune else tune,
                                     engine=engine if args.engine_map else None))
        fit = fit_runs(runs)
        theta = list(fit.parameters.values())
        fitted = solver_for(tune, engine, theta)
        params = fitted.params
        solver_kw = {"secondary_friction_torque_nm": fitted.secondary_friction_torque_nm,
                     "flyweight_radius_offset_m": fitted.flyweight_radius_offset_m}
    curve = predict_shift_curve(tune, engine, n_points=args.points, params=params, closing=closing, **solver_kw)
    if not args.no_sensitivity:
        curve.sensitivities = sensitivities(tune, engine, params, closing=closing, **solver_kw)
    measured = measured_points(args.run) if args.run else []
    comparison = compare_to_measured(curve, measured) if measured else None
    if comparison:
        # the same prediction the fit's residuals are of: each point at its measured secondary rpm and load
        has_tune = (Path(args.run) / "tune.toml").exists()
        at_load = residual_summary([load_fit_run(args.run, tune=None if has_tune else tune, engine=engine)], theta)
        comparison["at_measured_load"] = {k: at_load[k] for k in ("n", "rms_rpm", "mean_rpm", "max_abs_rpm")}
        comparison["engine_map"] = str(map_path)

    data = curve.to_dict()
    data["engine_map"] = str(map_path)
    data["phase"] = args.phase
    if comparison:
        data["measured"] = measured
        data["comparison"] = comparison
    if fit:
        data["fit"] = fit.to_dict()
    if args.png:
        _plot(curve, measured, args.png)
    if args.json:
        json.dump(data, sys.stdout, indent=2, default=float)
        sys.stdout.write("\n")
        return 0
    if fit:
        from dyno.tuning.fit import format_fit

        print(format_fit(fit))
    print(f"predicted shift curve: {tune.name}  (engine map {Path(map_path).name}, {args.phase}"
          f"{', fitted parameters' if fit else ''})")
    print(f"  engagement   {curve.engagement_rpm:8.0f} rpm")
    print(f"  shift-out    {curve.shift_out_rpm:8.0f} rpm   (upshift starts, ratio {curve.ratio_low_stop:.2f})")
    print(f"  full shift   {curve.full_shift_rpm:8.0f} rpm   (ratio {curve.ratio_high_stop:.2f})")
    print(f"  {'segment':<10}{'ratio':>7}{'engine rpm':>12}{'sec rpm':>10}{'sec N·m':>9}{'eff':>8}")
    step = max(1, len(curve.points) // 15)
    for p in curve.points[::step]:
        print(f"  {p.segment:<10}{p.ratio:7.3f}{p.engine_rpm:12.0f}{p.secondary_rpm:10.0f}"
              f"{p.secondary_torque_nm:9.2f}{p.efficiency:8.4f}")
    if curve.sensitivities:
        print("  sensitivity           unit          engagement  shift-out  full-shift")
        for name, s in curve.sensitivities.items():
            print(f"  {name:<36}{s['unit']:<12}{s['engagement_rpm']:9.2f}{s['shift_out_rpm']:11.2f}"
                  f"{s['full_shift_rpm']:11.2f}")
    if comparison:
        print(f"  measured run {args.run}: {comparison['n']} points, engine rpm residual "
              f"mean {comparison['mean_rpm']:+.0f}, rms {comparison['rms_rpm']:.0f}, max |{comparison['max_abs_rpm']:.0f}| rpm "
              f"(on the full-throttle curve)")
        c = comparison["at_measured_load"]
        print(f"    at each point's measured load (the fit's prediction{', fitted' if fit else ', nominal'}): "
              f"mean {c['mean_rpm']:+.0f}, rms {c['rms_rpm']:.0f}, max |{c['max_abs_rpm']:.0f}| rpm; "
              f"engine map {Path(map_path).name}")
    if args.png:
        print(f"  plot saved to {args.png}")
    return 0


def _plot(curve, measured, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = curve.arrays()
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 7), sharex=True)
    ax1.plot(a["secondary_rpm"], a["engine_rpm"], "-", label="predicted")
    ax1.axhline(curve.shift_out_rpm, ls="--", color="grey", label="ideal constant engine rpm")
    ax2.plot(a["secondary_rpm"], a["efficiency"], "-", label="predicted (closed form)")
    if measured:
        ax1.plot([m["secondary_rpm"] for m in measured], [m["engine_rpm"] for m in measured], "o", label="measured")
        ax2.plot([m["secondary_rpm"] for m in measured], [m["efficiency"] for m in measured], "o", label="measured")
    ax1.set_ylabel("engine rpm")
    ax2.set_ylabel("efficiency")
    ax2.set_xlabel("secondary rpm")
    ax1.set_title(f"predicted shift curve: {curve.tune_name}")
    ax1.legend()
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
