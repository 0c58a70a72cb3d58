#!/usr/bin/env python3
"""Belt-model benchmark: error against run time, stiff/extreme cases, performance figures.

Run:  python bench/bench_model.py [--quick]

Prints (does not assert):
1. error vs run time for each tier (capstan, closed form, full BVP at several
   tolerances and slip thresholds) against the tightest converged full-model
   solution (tol 1e-4, slip threshold 1e-4 m/s), for the axial forces and the
   efficiencies; and a PNG of it into bench/out/;
2. the stiff/extreme-case table (converged and verified, or the
   DidNotConverge message);
3. the performance figures of issue 3: Table 6.1 from no starting solution,
   from a neighbouring solution, a 20-point sweep, closed form per point;
4. the cold-start grid (issue 14): ratio {0.9 ... 3.5} x torque {5, 10, 18} N*m x
   both variants, each solved from no starting solution: time, state (steady /
   gross_slip / failed with its reason), force/moment/power balances, efficiency
   (``--only grid`` for this table alone).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dyno.errors import DidNotConverge  # noqa: E402
from dyno.model import bvp, capstan, closed_form, sweep  # noqa: E402
from dyno.model.params import TABLE_6_1, TABLE_6_1_POINT  # noqa: E402
from dyno.model.solution import solve_point  # noqa: E402

OUT = Path(__file__).resolve().parent / "out"


def rel(a, b):
    return abs(a - b) / abs(b)


def errors(fz_p, fz_s, eta, ref):
    r = ref.summary
    return (
        rel(fz_p, r["axial_force_n"]["primary"]),
        rel(fz_s, r["axial_force_n"]["secondary"]),
        abs(eta - r["efficiency"]["overall"]),
    )


def table_error_vs_time(quick: bool):
    print("\n== 1. Error against run time (Table 6.1 case; reference: full BVP, tol 1e-4, v_th 1e-4 m/s) ==")
    t0 = time.perf_counter()
    base = solve_point()
    ref = solve_point(tol=1e-4, guess=base, nodes=500, time_limit_s=600)
    print(f"reference solved in {time.perf_counter() - t0:.1f} s ({ref.summary['mesh_nodes']} nodes)")
    rows = []
    n = 2000
    t = time.perf_counter()
    for _ in range(n):
        c = capstan.capstan_point(TABLE_6_1, TABLE_6_1_POINT)
    rows.append(("capstan", "-", "-", (time.perf_counter() - t) / n, *errors(c.axial_force_primary_n, c.axial_force_secondary_n, c.efficiency_overall, ref)))
    t = time.perf_counter()
    for _ in range(n):
        c = closed_form.closed_form_point(TABLE_6_1, TABLE_6_1_POINT)
    rows.append(("closed form", "-", "-", (time.perf_counter() - t) / n, *errors(c.axial_force_primary_n, c.axial_force_secondary_n, c.efficiency_overall, ref)))
    tols = (1e-2, 3e-3, 1e-3) if quick else (1e-2, 3e-3, 1e-3, 3e-4)
    slips = (1e-2, 1e-3, 1e-4) if quick else (1e-2, 1e-3, 3e-4, 1e-4)
    for corner in (0.0, 0.2):
        for slip in slips:
            for tol in tols:
                t = time.perf_counter()
                try:
                    s = solve_point(slip_threshold_m_s=slip, tol=tol, friction_corner=corner, time_limit_s=120)
                except DidNotConverge as exc:
                    rows.append((f"full BVP corner={corner}", tol, slip, time.perf_counter() - t, math.nan, math.nan, math.nan))
                    print("  failed:", str(exc)[-120:])
                    continue
                rows.append((f"full BVP corner={corner}", tol, slip, time.perf_counter() - t,
                             *errors(s.summary["axial_force_n"]["primary"], s.summary["axial_force_n"]["secondary"],
                                     s.summary["efficiency"]["overall"], ref)))
    print(f"{'tier':<22}{'tol':>8}{'v_th m/s':>10}{'run s':>11}{'err F_P':>10}{'err F_S':>10}{'err eta (abs)':>15}")
    for name, tol, slip, dt, ep, es, ee in rows:
        print(f"{name:<22}{tol!s:>8}{slip!s:>10}{dt:>11.4g}{ep:>10.2e}{es:>10.2e}{ee:>15.2e}")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        OUT.mkdir(parents=True, exist_ok=True)
        fig, ax = plt.subplots(figsize=(7, 5))
        for name, tol, slip, dt, ep, es, ee in rows:
            if math.isnan(ep):
                continue
            err = max(ep, es, 1e-9)
            ax.loglog(dt, err, "o" if "BVP" in name else "s")
            ax.annotate(f"{name.replace('full BVP ', '')} {tol} {slip}", (dt, err), fontsize=6)
        ax.set_xlabel("run time [s]")
        ax.set_ylabel("max relative axial-force error")
        ax.set_title("belt model: error vs run time (Table 6.1)")
        ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        fig.savefig(OUT / "model_error_vs_time.png", dpi=120)
        print(f"PNG: {OUT / 'model_error_vs_time.png'}")
    except Exception as exc:  # the table matters more than the plot
        print("plot skipped:", exc)
    return base


def table_extremes(base):
    print("\n== 2. Stiff and extreme cases (warm start from Table 6.1, rounded corner, 30 s limit) ==")
    cases = [
        ("slip 1e-2 m/s", TABLE_6_1, TABLE_6_1_POINT, 1e-2),
        ("slip 1e-3 m/s", TABLE_6_1, TABLE_6_1_POINT, 1e-3),
        ("slip 1e-4 m/s", TABLE_6_1, TABLE_6_1_POINT, 1e-4),
        ("slip 1e-5 m/s", TABLE_6_1, TABLE_6_1_POINT, 1e-5),
        ("EI 0.01", TABLE_6_1.with_belt(bending_stiffness_nm2=0.01), TABLE_6_1_POINT, 1e-4),
        ("EI 0.1", TABLE_6_1.with_belt(bending_stiffness_nm2=0.1), TABLE_6_1_POINT, 1e-4),
        ("EI 1.0", TABLE_6_1.with_belt(bending_stiffness_nm2=1.0), TABLE_6_1_POINT, 1e-4),
        ("slack 10 N", TABLE_6_1, replace(TABLE_6_1_POINT, slack_tension_n=10.0), 1e-4),  # gross slip at 18 N*m
        ("slack 10 N, 2 N*m", TABLE_6_1, replace(TABLE_6_1_POINT, slack_tension_n=10.0, primary_torque_nm=2.0), 1e-4),
        ("slack 30 N", TABLE_6_1, replace(TABLE_6_1_POINT, slack_tension_n=30.0), 1e-4),
        ("ratio 2.0", TABLE_6_1, replace(TABLE_6_1_POINT, ratio=2.0), 1e-4),
        ("ratio 0.6", TABLE_6_1, replace(TABLE_6_1_POINT, ratio=0.6), 1e-4),
        ("7600 rpm", TABLE_6_1, replace(TABLE_6_1_POINT, primary_speed_rpm=7600.0), 1e-4),
        ("beta 8 deg", TABLE_6_1.with_sheave_angle(8.0), TABLE_6_1_POINT, 1e-4),
        ("beta 16 deg", TABLE_6_1.with_sheave_angle(16.0), TABLE_6_1_POINT, 1e-4),
    ]
    guess = solve_point(guess=base, friction_corner=0.2)
    print(f"{'case':<20}{'result':<12}{'run s':>7}{'resid':>10}{'F_P N':>9}{'F_S N':>9}{'eta':>8}  note")
    for name, params, op, slip in cases:
        t = time.perf_counter()
        try:
            s = solve_point(params, op, slip_threshold_m_s=slip, guess=guess, friction_corner=0.2, time_limit_s=30)
            raw = s.raw
            bc = bvp.make_bc(raw.case)(raw.y[:, 0], raw.y[:, -1], raw.p)
            verified = raw.residual_max <= raw.tol and abs(bc).max() < raw.tol
            sm = s.summary
            print(f"{name:<20}{'verified' if verified else 'UNVERIFIED':<12}{time.perf_counter() - t:>7.1f}"
                  f"{raw.residual_max:>10.2e}{sm['axial_force_n']['primary']:>9.1f}{sm['axial_force_n']['secondary']:>9.1f}"
                  f"{sm['efficiency']['overall']:>8.4f}")
        except DidNotConverge as exc:
            msg = str(exc)
            print(f"{name:<20}{'DidNotConv':<12}{time.perf_counter() - t:>7.1f}{'':>36}  {msg[msg.index(': ', 30) + 2:][:90]}"
                  + (" ... GROSS SLIP (capstan bound reached): beyond the model" if "gross slip" in msg else ""))


def table_performance(base):
    print("\n== 3. Performance against the issue-3 targets (ratio = measured / target; < 1 meets it) ==")
    rows = []

    def row(label, seconds, target_s, note=""):
        rows.append((label, seconds, target_s, note))
        print(f"  {label}: {seconds:.3g} s", flush=True)

    t = time.perf_counter()
    s = solve_point()
    row("Table 6.1 from no starting solution (sharp corner, default)", time.perf_counter() - t, 20.0,
        f"{s.summary['mesh_nodes']} nodes, {s.summary['continuation_steps']} steps")
    t = time.perf_counter()
    sr = solve_point(friction_corner=0.2)
    row("Table 6.1 from no starting solution (rounded corner 0.2)", time.perf_counter() - t, 20.0,
        f"{sr.summary['mesh_nodes']} nodes")
    for label, op in (("slack 100->105 N", replace(TABLE_6_1_POINT, slack_tension_n=105.0)),
                      ("torque 18->19 N*m", replace(TABLE_6_1_POINT, primary_torque_nm=19.0)),
                      ("ratio 1.00->1.02", replace(TABLE_6_1_POINT, ratio=1.02))):
        t = time.perf_counter()
        w = solve_point(TABLE_6_1, op, guess=s)
        row(f"warm start from the neighbour, {label}", time.perf_counter() - t, 2.0, f"{w.summary['mesh_nodes']} nodes")
    for corner, tol in ((0.0, 1e-3), (0.2, 1e-3), (0.2, 1e-2)):
        start = s if corner == 0 else sr
        t = time.perf_counter()
        rows_, _ = sweep.sweep_operating_range(20, start=start, friction_corner=corner, tol=tol)
        n_ok = sum(bool(r["converged"]) for r in rows_)
        row(f"20-point sweep 1.74..0.72, corner={corner}, tol={tol:g}", time.perf_counter() - t, 60.0,
            f"{n_ok}/20 converged")
    n = 5000
    t = time.perf_counter()
    for _ in range(n):
        closed_form.closed_form_point(TABLE_6_1, TABLE_6_1_POINT)
    row("closed-form axial thrusts, per point", (time.perf_counter() - t) / n, 1e-3)
    print(f"\n{'item':<62}{'measured s':>12}{'target s':>10}{'ratio':>8}  {'':<6} note")
    for label, sec, target, note in rows:
        ratio = sec / target
        print(f"{label:<62}{sec:>12.4g}{target:>10.4g}{ratio:>8.2f}  {'met' if ratio < 1 else 'MISSED':<6} {note}")
    try:
        import os

        print(f"(load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; timings scale with load)")
    except OSError:
        pass


GRID_RATIOS = (0.9, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5)
GRID_TORQUES_NM = (5.0, 10.0, 18.0)


def _stock_tune_clamp_n(ratio: float) -> float:
    """The stock tune's primary clamping force at 3400 rpm and this ratio's primary radius (spring + flyweights)."""
    from dyno.model import geometry
    from dyno.tuning import actuators
    from dyno.tuning.tune import load_tune

    tune = load_tune(Path(__file__).resolve().parents[1] / "calibration" / "tunes" / "cvtech-stock.toml")
    r_p, _ = geometry.radii_for_ratio(ratio, TABLE_6_1.belt.pitch_length_m, TABLE_6_1.drive.centre_distance_m)
    return float(actuators.primary_axial_force_n(tune, TABLE_6_1_POINT.primary_speed_rpm, r_p))


def table_grid(variants=("corrected", "as_published")):
    """Cold solve (no starting solution) at every grid point: time, state, balances, efficiency."""
    print("\n== 4. Cold start on the grid: ratio R_S/R_P x primary torque x {slack 100 N, stock tune's clamp at "
          "3400 rpm}, v_th 1e-4 m/s, tol 1e-3 ==")
    print(f"{'variant':<13}{'level':>14}{'ratio':>6}{'torque':>7}{'time s':>8}  {'state':<11}{'force':>9}{'moment':>9}"
          f"{'power':>9}{'eta':>8}  reason")
    worst = {}
    for variant in variants:
        for level in ("slack 100 N", "stock clamp"):
            for ratio in GRID_RATIOS:
                for torque in GRID_TORQUES_NM:
                    op = replace(TABLE_6_1_POINT, ratio=ratio, primary_torque_nm=torque)
                    label = level
                    if level == "stock clamp":
                        clamp = _stock_tune_clamp_n(ratio)
                        op = replace(op, slack_tension_n=None, primary_axial_force_n=clamp)
                        label = f"F_P={clamp:.0f} N"
                    t0 = time.perf_counter()
                    try:
                        s = solve_point(TABLE_6_1, op, variant=variant, time_limit_s=60).summary
                        dt = time.perf_counter() - t0
                        b = s["balance"]
                        print(f"{variant:<13}{label:>14}{ratio:>6.2f}{torque:>7.1f}{dt:>8.2f}  {s['state']:<11}"
                              f"{b['force_rel']:>9.1e}{b['moment_rel']:>9.1e}{b['power_rel']:>9.1e}"
                              f"{s['efficiency']['overall']:>8.4f}")
                    except Exception as exc:  # noqa: BLE001  (the table reports every outcome)
                        dt = time.perf_counter() - t0
                        state = "gross_slip" if type(exc).__name__ == "GrossSlip" else "failed"
                        print(f"{variant:<13}{label:>14}{ratio:>6.2f}{torque:>7.1f}{dt:>8.2f}  {state:<11}{'':>35}  "
                              f"{str(exc)[-200:]}")
                    key = (variant, level)
                    worst[key] = max(worst.get(key, 0.0), dt)
    for (variant, level), dt in worst.items():
        print(f"max cold solve time, {variant}, {level}: {dt:.1f} s (goal <= 5 s)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer tolerance/threshold combinations")
    ap.add_argument("--only", choices=("errors", "extremes", "performance", "grid"), default=None)
    args = ap.parse_args()
    base = None
    if args.only == "grid":
        table_grid()
        return 0
    if args.only in (None, "errors"):
        base = table_error_vs_time(args.quick)
    if base is None:
        base = solve_point()
    if args.only in (None, "extremes"):
        table_extremes(base)
    if args.only in (None, "performance"):
        table_performance(base)
    if args.only is None:
        table_grid()
    return 0


if __name__ == "__main__":
    sys.exit(main())
