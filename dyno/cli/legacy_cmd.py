"""dyno import-legacy: turn a folder of the thesis rig's logs into a dyno run directory."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path


def add_arguments(p) -> None:
    p.add_argument("dir", type=Path, help="one run folder of the thesis rig (P_N.csv, S_N.csv, ADC_N.csv, TORQUE_N.csv)")
    p.add_argument("--out", type=Path, default=None,
                   help="run directory to create (default: runs/legacy-<folder>); must be new or empty")
    p.add_argument("--calibration", type=Path, default=None,
                   help="cal_values.csv or a dyno calibration history (default: found in DIR or its parent)")
    p.add_argument("--engine-map", type=Path, default=None,
                   help="engine map, headerless rpm,hp or with a header (default: engine_power_RPM.csv in DIR or its parent)")
    p.add_argument("--discard", type=lambda s: [int(x) for x in s.split(",") if x.strip()], default=[0],
                   metavar="N[,N...]", help="legacy point numbers the team discarded (default: 0, taken before loading)")
    p.add_argument("--json", action="store_true", help="print one JSON document: run_dir, points, faults, summary")


def run(args) -> int:
    from dyno.session.summary import public_point
    from dyno.runlog.legacy import import_legacy

    result = import_legacy(args.dir, args.out, calibration_path=args.calibration,
                           engine_map_path=args.engine_map, discard=args.discard)
    from dyno.library.index import index_after_run

    index_after_run(result["run_dir"], lambda line: print(f"dyno import-legacy: {line}", file=sys.stderr))
    points = [{**public_point(p), "legacy_point": p["legacy_point"], "discarded": p["discarded"]}
              for p in result["points"]]
    faults = [{k: f[k] for k in ("point", "channel", "severity", "reason", "source")} for f in result["faults"]]
    if args.json:
        print(json.dumps({"run_dir": result["run_dir"], "source": result["source"], "points": points,
                          "faults": faults, "summary": result["summary"]}, indent=1, default=str))
        return 0
    print(f"{result['source']} -> {result['run_dir']}")
    print(f"{'N':>3} {'rpm_p':>6} {'rpm_s':>6} {'T_s N·m':>8} {'eff %':>6}  note")
    for p in points:
        eta = p.get("efficiency")
        note = "discarded" if p["discarded"] else ("" if p.get("valid") else "no efficiency")
        print(f"{p['legacy_point']:>3} {_f(p.get('rpm_primary'), 0):>6} {_f(p.get('rpm_secondary'), 0):>6} "
              f"{_f(p.get('torque_secondary_nm'), 2):>8} {_f(None if eta is None else 100 * eta, 1):>6}  {note}")
    s = result["summary"]
    print(f"{s['n_valid']} valid of {s['n_points']} points; faults: "
          + (", ".join(f"{n} {k}" for k, n in sorted(s["faults_by_severity"].items())) or "none"))
    for f in faults:
        print(f"  point {f['point']:>2} {f['channel']:<11} {f['severity']:<7} {f['reason']}")
    return 0


def _f(x, digits: int) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return f"{x:.{digits}f}"
