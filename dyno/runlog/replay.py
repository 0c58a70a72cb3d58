"""Re-process a logged run from its raw streams (optionally with another calibration or engine map).

Uses the very function the live controller used (:func:`dyno.analysis.points.reduce_point`)
on the very events it logged, so with the run's own calibration and map the
points come out identical.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

from dyno.analysis.points import reduce_point
from dyno.runlog.reader import load_run

PASS_THROUGH = ("settled_by", "settle_s", "host_t_start_s", "host_t_end_s", "step_s", "efficiency_true",
                "rpm_primary_true", "rpm_secondary_true", "torque_secondary_true_nm", "power_in_true_w",
                "power_out_true_w", "ratio_geometric_true", "belt_slip_true", "legacy_point", "discarded",
                "legacy_faults", "thesis_torque_nm", "legacy_channels", "setpoint_rpm", "setpoint", "hold_variable",
                "ramp_rate_rpm_s", "torque_input_true_nm", "driveline_loss_true_nm")
# Fields a fault found at import/acquisition time withholds (the raw data cannot support them).
WITHHELD_BY_FATAL = ("efficiency", "efficiency_sem")


def replay(run_dir, calibration_path=None, engine_map_path=None, ambient=None) -> dict:
    """The run's points re-processed (``ambient``: another day than the run's, a
    :class:`dyno.analysis.air.Ambient`; ``Ambient()`` re-processes it uncorrected)."""
    from dyno.analysis.calibration_history import CalibrationEntry, latest, load_history
    from dyno.analysis.engine_map import load_engine_map

    run = load_run(run_dir)
    if calibration_path is not None:
        calibration = latest(load_history(calibration_path))
    elif run.calibration is not None:
        calibration = CalibrationEntry.from_dict(run.calibration)
    else:
        from dyno.errors import ConfigError

        raise ConfigError(run.path, "calibration.json", "the run's calibration (or pass --calibration FILE)")
    tares = run.docs("tare")
    if tares:  # the points were measured from the zero read at rest before GO: so are the replayed ones
        import dataclasses

        calibration = dataclasses.replace(calibration, intercept_counts=float(tares[-1]["zero_counts"]))
    engine_map = load_engine_map(engine_map_path or run.engine_map_path)
    from dyno.analysis.air import Ambient

    ambient = ambient if ambient is not None else Ambient.from_dict(run.meta.get("ambient"))
    site_m = ((run.meta.get("uncertainty") or {}).get("air_day") or {}).get("altitude_m")
    air_rel = ambient.air_rel_u(site_m) if "ambient" in run.meta or ambient.corrected else 0.0
    if ambient.corrected:  # the run's day (SAE J1349), as the run itself took it
        engine_map = engine_map.at_ambient(ambient.temp_c, ambient.dry_pressure_kpa)
    from dyno.analysis.input_torque import channel_from_meta

    tares_in = run.docs("tare_input")
    input_channel = channel_from_meta(run.meta, tares_in[-1] if tares_in else None)  # None: no input channel
    points = []
    for doc in run.points:
        # the throttle the point was measured at, as recorded (runs before it was recorded: full)
        p = reduce_point(run.streams, doc["t_start_us"], doc["t_end_us"], calibration, engine_map,
                         index=doc.get("index"), throttle_frac=doc.get("throttle_frac", 1.0))
        if "inertia_engine_kg_m2" in doc:  # a ramp point (plan step "ramp"): the same I·alpha correction
            from dyno.analysis.inertia import correct_inertia

            p = correct_inertia(p, run.streams, engine_map, doc["inertia_engine_kg_m2"],
                                doc["inertia_secondary_kg_m2"])
        for k in PASS_THROUGH:
            if k in doc:
                p[k] = doc[k]
        unc = run.meta.get("uncertainty")
        if unc and "efficiency_sys95" in doc:  # the run's stated systematic terms, on the re-processed point
            from dyno.analysis.systematic import calibration_rel_for, interval_basis, point_systematic

            p.update(point_systematic(p, calibration_rel_for(unc["torque_calibration_rel"], p, tares[-1] if tares
                                                             else None), unc["engine_map_rel"],
                                      air_rel, **interval_basis(_basis(unc, ambient, run.meta), p)))
        if input_channel is not None:  # as the run did: the measured input power, the map's figure beside
            from dyno.analysis.input_torque import input_point, input_systematic
            from dyno.analysis.systematic import calibration_rel_for, driveline_bound

            p.update(input_point(run.streams, p, input_channel))
            if unc:
                p.update(input_systematic(p, calibration_rel_for(unc["torque_calibration_rel"], p, tares[-1] if tares
                                                                 else None), input_channel,
                                          driveline_bound(p, unc)))
        fatal = [f for f in doc.get("legacy_faults", ()) if f.get("severity") == "error"]
        if fatal and not math.isnan(p["efficiency"]):
            # A fault recorded with the run (e.g. a glitch the importer found) still
            # withholds the number on re-processing: a replay never resurrects it.
            for k in WITHHELD_BY_FATAL:
                p[k] = math.nan
            p["valid"] = False
            p["faults"] = p["faults"] + [{"channel": f["channel"], "reason": f["reason"], "severity": "error"}
                                         for f in fatal]
            p["withheld_by_import"] = True
        points.append(p)
    plan_path = run.path / "plan.toml"
    extra = {"uncertainty_basis": _basis(run.meta.get("uncertainty") or {}, ambient, run.meta)}
    if run.docs("grid_cell"):  # a drive grid: its table from the re-processed points (dyno.analysis.drive_grid)
        from dyno.analysis.drive_grid import grid_table

        extra["drive_grid"] = grid_table(run.docs("grid_cell"), points)
    return {**extra, "run_dir": str(run.path), "points": points, "stop": run.stop, "torn": run.torn,
            "plan": run.meta.get("plan"), "plan_text": plan_path.read_text() if plan_path.is_file() else None,
            "aborts": run.docs("abort"), "meta": run.meta, "calibration": calibration.to_dict(),
            "engine_map": str(engine_map.source), "ambient": ambient.to_dict()}


CSV_COLUMNS = ("index", "throttle_frac", "rpm_primary", "rpm_primary_std", "rpm_secondary", "rpm_secondary_std", "ratio",
               "torque_secondary_nm", "torque_secondary_std_nm", "power_out_w", "power_in_w", "efficiency",
               "efficiency_sem", "n_primary_edges", "n_secondary_edges", "n_adc", "n_adc_error", "duration_s",
               "t_start_us", "t_end_us", "settled_by", "valid", "efficiency_true", "efficiency_reason",
               "efficiency_source", "torque_input_nm", "efficiency_engine_map", "efficiency_u95")


def points_csv(points) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(CSV_COLUMNS)
    for p in points:
        w.writerow(["" if p.get(c) is None else p.get(c) for c in CSV_COLUMNS])
    return buf.getvalue()


def export(run_dir, out_dir=None, **kw) -> list[Path]:
    """Write points.csv and the raw streams as CSV (primary/secondary edges, ADC)."""
    from dyno.fileio import write_atomic

    result = replay(run_dir, **kw)
    run = load_run(run_dir)
    out = Path(out_dir) if out_dir else Path(run_dir) / "export"
    out.mkdir(parents=True, exist_ok=True)
    written = []
    write_atomic(out / "points.csv", points_csv(result["points"]))
    written.append(out / "points.csv")
    s = run.streams
    for name, ch in (("primary_edges", 1), ("secondary_edges", 2)):
        rows = "t_us\n" + "".join(f"{t}\n" for t in s.edges[ch])
        write_atomic(out / f"{name}.csv", rows)
        written.append(out / f"{name}.csv")
    rows = "t_us,adc_code,status\n" + "".join(f"{t},{c},{st}\n" for t, c, st in zip(s.adc_t, s.adc_code, s.adc_status))
    write_atomic(out / "adc.csv", rows)
    written.append(out / "adc.csv")
    if s.input_t:  # the engine-side input torque converter (issue 27)
        rows = "t_us,input_code,status\n" + "".join(
            f"{t},{c},{st}\n" for t, c, st in zip(s.input_t, s.input_code, s.input_status))
        write_atomic(out / "input_adc.csv", rows)
        written.append(out / "input_adc.csv")
    return written


def _basis(unc: dict, ambient, meta: dict) -> dict:
    """The interval's inputs for the replayed air (an ``--ambient`` given now corrects an uncorrected run;
    a run from before the air was stated has no air term)."""
    day = unc.get("air_day") or {}
    known = ambient.corrected or "ambient" not in meta
    return {**unc, "air_day": None if known else {"altitude_m": day.get("altitude_m")}}
