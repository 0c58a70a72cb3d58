"""``dyno design``: the Arango & Munoz (2020) CVT design method."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

from dyno.resources import resource


def add_arguments(parser) -> None:
    parser.add_argument("--requirements", required=True, metavar="FILE",
                        help="route/vehicle requirements TOML (see calibration/design/)")
    parser.add_argument("--catalogue", metavar="CSV", default=str(resource("calibration/belt_catalogue.csv")),
                        help="belt section catalogue (default: calibration/belt_catalogue.csv)")
    parser.add_argument("--out", metavar="DIR", help="directory for design.json, summary.txt and profile "
                                                      "CSVs (default: ./<name>-design)")
    parser.add_argument("--json", action="store_true", help="print the full design as JSON")


def _write_csv(path: Path, columns: dict[str, list]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        w.writerows(zip(*columns.values()))


def run(args) -> int:
    from dyno.tuning.design import design
    from dyno.tuning.design_inputs import load_belt_catalogue, load_requirements

    req = load_requirements(args.requirements)
    result = design(req, load_belt_catalogue(args.catalogue))
    lines = [f"CVT design: {req.name}  (Arango & Munoz 2020)"]
    for label, value, unit in result.summary_rows():
        val = f"{value:.4g}" if isinstance(value, float) else str(value)
        lines.append(f"  {label:<48} {val:>14} {unit}")
    lines += [f"  note: {n}" for n in result.notes]
    text = "\n".join(lines) + "\n"

    out = Path(args.out) if args.out else Path.cwd() / f"{req.name}-design"
    out.mkdir(parents=True, exist_ok=True)
    data = result.to_dict()
    (out / "design.json").write_text(json.dumps(data, indent=2) + "\n")
    (out / "summary.txt").write_text(text)
    ramp, cam, tcam = result.weight_ramp, result.flyweight_cam, result.torque_cam
    _write_csv(out / "weight_ramp.csv", {k: ramp[k] for k in (
        "speed_rpm", "radius_mm", "axial_mm", "centrifugal_force_n", "clamp_force_n", "ramp_angle_deg",
        "mechanical_advantage")})
    _write_csv(out / "flyweight_cam.csv", {
        "flyweight_angle_deg": cam["flyweight_angle_deg"],
        "profile_x_mm": [p[0] for p in cam["profile_mm"]],
        "profile_y_mm": [p[1] for p in cam["profile_mm"]],
        "contact_slope_deg": cam["contact_slope_deg"]})
    _write_csv(out / "torque_cam.csv", {k: tcam[k] for k in (
        "torque_nm", "spring_force_n", "tangential_force_n", "angle_deg", "mechanical_advantage",
        "axial_mm", "peripheral_mm")})

    if args.json:
        json.dump(data, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(text)
        print(f"  saved to {out}")
    return 0
