"""dyno replay: re-process a logged run (opens the viewer; --json stays headless)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path


def add_arguments(p) -> None:
    p.add_argument("run", type=Path, nargs="+", help="run directory (several to overlay in the viewer)")
    p.add_argument("--calibration", type=Path, default=None, help="re-process with this calibration history")
    p.add_argument("--engine-map", type=Path, default=None, help="re-process with this engine map")
    p.add_argument("--json", action="store_true", help="print the points as one JSON document, no viewer")
    p.add_argument("--driven-loss", type=Path, default=None, metavar="FILE",
                   help="with --json: add a coast-down's driven-side loss (driven_loss.json) back to each point's "
                        "efficiency as extra keys, uncertainty propagated")
    p.add_argument("--measured-map", type=Path, default=None, metavar="FILE",
                   help="a run with the input torque channel: the engine's measured full-throttle torque against "
                        "its map, printed (no viewer), and saved as an engine map (standard day) for --engine-map")


def run(args) -> int:
    from dyno.session.summary import public_point
    from dyno.runlog.replay import replay

    if getattr(args, "measured_map", None) is not None:
        return _measured_map(args, [replay(r, args.calibration, args.engine_map) for r in args.run])
    if not args.json and importlib.util.find_spec("dyno.ui.replay_app") is not None:
        from dyno.runlog.reader import load_run
        from dyno.ui.replay_app import main as viewer

        for r in args.run:  # a bad path or run is one line here, before the screen is taken over
            load_run(r, with_events=False)

        return viewer(args)
    results = [replay(r, args.calibration, args.engine_map) for r in args.run]
    if args.json:
        loss = None
        if getattr(args, "driven_loss", None) is not None:
            from dyno.analysis.coastdown import load_driven_loss

            loss = load_driven_loss(args.driven_loss)

        def pub(p, r):
            out = public_point(p)
            if loss is not None:
                from dyno.analysis.coastdown import driven_loss_keys

                out.update(driven_loss_keys(out, loss, r.get("uncertainty_basis")))
            return out

        docs = [{"run_dir": r["run_dir"], "points": [pub(p, r) for p in r["points"]],
                 "stop": r["stop"], "aborts": r["aborts"], "torn": r["torn"],
                 **({"drive_grid": r["drive_grid"]} if "drive_grid" in r else {})} for r in results]
        print(json.dumps(docs[0] if len(docs) == 1 else docs, indent=1, default=str))
        return 0
    from dyno.cli.run_cmd import print_result_table

    for r in results:
        print_result_table({"run_dir": r["run_dir"], "state": (r["stop"] or {}).get("exit_status", "killed?"),
                      "reason": (r["stop"] or {}).get("reason", "no stop document"),
                      "points": [public_point(p) for p in r["points"]],
                      "frames": {"read": "-", "accepted": "-", "rejected": "-"}, "events_lost": "-",
                      "aborts": r["aborts"]})
    return 0


def _measured_map(args, results) -> int:
    """``--measured-map FILE``: the engine's measured curve against its map; the file in the map format."""
    from dyno.analysis.air import Ambient
    from dyno.analysis.engine_map import load_engine_map
    from dyno.analysis.measured_map import describe, measured_curve, write_map
    from dyno.errors import ConfigError
    from dyno.runlog.reader import load_run

    if len(results) != 1:
        raise ConfigError("command line", "--measured-map", "one run")
    r = results[0]
    emap = load_engine_map(args.engine_map or load_run(r["run_dir"], with_events=False).engine_map_path)
    amb = Ambient.from_dict(r.get("ambient"))
    if amb.corrected:  # the engine made the day's torque: compare with the map taken to the day
        emap = emap.at_ambient(amb.temp_c, amb.dry_pressure_kpa)
    curve = measured_curve(r["points"], emap)
    if len(curve) < 2:
        raise ConfigError(r["run_dir"], "points", "full-throttle points with the input torque channel "
                          f"(torque_input_nm) at two engine speeds at least; found {len(curve)}")
    cf = amb.j1349_factor if amb.corrected else None
    std = [dict(row, torque_nm=row["torque_nm"] * cf, torque_u95_nm=row["torque_u95_nm"] * cf) if cf else row
           for row in curve]  # a map is a standard-day map (SAE J1349): the day's torque taken back to it
    write_map(std, args.measured_map, source=f"{r['run_dir']}" + (f", J1349 CF {cf:.4f}" if cf else
                                                                  " (air not known: the day's torque as measured)"))
    if args.json:
        print(json.dumps({"run_dir": r["run_dir"], "measured_engine": curve, "written": str(args.measured_map),
                          "j1349_factor": cf}, indent=1, default=str))
    else:
        print("\n".join(describe(curve)))
        print(f"written: {args.measured_map}")
    return 0
