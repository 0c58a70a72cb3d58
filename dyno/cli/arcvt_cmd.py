"""``dyno arcvt``: AR-CVT actuation model (van Kerkhoven 2006)."""

from __future__ import annotations

import json
import sys
import tomllib
from pathlib import Path

from dyno.cli import number_in


def add_arguments(parser) -> None:
    parser.add_argument("--params", metavar="TOML", help="overrides of the report's Tables 3.1-3.3 "
                                                          "(keys of dyno.tuning.arcvt.ArcvtParams)")
    parser.add_argument("--trace", metavar="CSV", help="engine-speed trace: columns time_s, engine_rpm")
    parser.add_argument("--rotation", choices=("cw", "ccw"), default="cw",
                        help="radial-pulley rotation for the trace (default cw, the report's choice)")
    parser.add_argument("--vroemen", action="store_true", help="use the report's eq. 3.24 horizontal force")
    parser.add_argument("--points", type=number_in(2, 1000, integer=True), default=12, help="rows of the geometry/force table")
    parser.add_argument("--json", action="store_true", help="print everything as JSON")


def run(args) -> int:
    from dyno.errors import ConfigError
    from dyno.tuning import arcvt

    overrides = {}
    if args.params:
        try:
            overrides = tomllib.loads(Path(args.params).read_text(encoding="utf-8"))
        except OSError as exc:
            raise ConfigError(args.params, "<file>", f"a readable TOML file ({exc.strerror})") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(args.params, "<toml>", f"valid TOML ({exc})") from None
    if args.vroemen:
        overrides["horizontal_force_model"] = "vroemen"
    p = arcvt.params_from_dict(overrides, args.params or "<arcvt params>")
    extremes = arcvt.geometry_extremes(p)
    coef, fit_err = arcvt.quadratic_fit(p)
    table = arcvt.actuation_table(p, args.points)
    trace = None
    if args.trace:
        t, n = arcvt.load_trace(args.trace)
        trace = arcvt.evaluate_trace(t, n, p, clockwise=args.rotation == "cw")
    if args.json:
        out = {"params": p.__dict__, "geometry": extremes, "quadratic_fit": {"coeffs": coef.tolist(),
               "max_error_m": fit_err}, "table": table}
        if trace:
            out["trace"] = trace
        json.dump(out, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    print("AR-CVT geometry (van Kerkhoven 2006, Table 3.1)")
    print(f"  belt length {p.belt_length_m * 1e3:.1f} mm, R_r {p.radial_radius_m * 1e3:.0f} mm")
    print(f"  R_a {extremes['axial_radius_min_m'] * 1e3:.0f}..{extremes['axial_radius_max_m'] * 1e3:.0f} mm -> "
          f"a_h {extremes['centre_distance_max_m'] * 1e3:.1f}..{extremes['centre_distance_min_m'] * 1e3:.1f} mm")
    print(f"  quadratic fit (eq. 3.5) max error {fit_err * 1e3:.2f} mm")
    print(f"  {'R_a mm':>7}{'a_h mm':>8}{'da/dR':>7}{'alpha':>7}{'F_hor':>8}{'F_vert':>8}"
          f"{'F_act cw':>10}{'F_act ccw':>10}{'T_act cw':>9}")
    for r in table:
        print(f"  {r['axial_radius_m'] * 1e3:7.1f}{r['centre_distance_m'] * 1e3:8.1f}{r['centre_distance_slope']:7.2f}"
              f"{r['alpha_rad'] * 57.29578:7.1f}{r['force_horizontal_n']:8.0f}{r['force_vertical_n']:8.0f}"
              f"{r['actuation_force_n']:10.0f}{r['actuation_force_ccw_n']:10.0f}{r['actuation_torque_nm']:9.1f}")
    if trace:
        print(f"  trace {args.trace} ({args.rotation}): max |shift rate| {trace['max_abs_shift_rate_m_s'] * 1e3:.1f} mm/s, "
              f"max power {trace['max_actuation_power_w']:.0f} W, max |torque| "
              f"{trace['max_abs_actuation_torque_nm']:.0f} N·m, max arm speed {trace['max_arm_speed_rad_s']:.2f} rad/s")
    return 0
