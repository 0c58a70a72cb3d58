#!/usr/bin/env python3
"""Benchmark: a full predicted shift curve (50 load points) with the
closed-form belt relations (target < 1 s).  Prints, never asserts.

    python bench/bench_shift_curve.py [--points 50] [--repeat 3] [--full] [--fit] [--quick]

``--full`` times the full belt model (dyno.model.solution.solve_point, BVP,
cheap settings tol 1e-2 / rounded friction corner) at one shift-curve point
driven by the primary axial force, cold and warm-started, and extrapolates
to a curve (each curve point is a root solve in engine rpm: ~8 belt solves).
``--fit`` times the rig fit's residual vector and one exact prediction
sweep on synthetic points (no sim run needed).  ``--quick`` (CI's smoke run) is accepted and
changes nothing: the default run takes a second or two.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--full", action="store_true", help="also time the full belt model (slow)")
    ap.add_argument("--fit", action="store_true", help="also time the rig fit's residuals")
    ap.add_argument("--quick", action="store_true",
                    help="CI smoke run: the same as the default run, which already takes a second or two")
    args = ap.parse_args()

    from dyno.tuning.shift_curve import EngineMap, load_engine_map, predict_shift_curve
    from dyno.tuning.tune import load_tune

    tune = load_tune(ROOT / "calibration/tunes/cvtech-stock.toml")
    maps = sorted((ROOT / "calibration/engine_maps").glob("*.csv"))
    engine = load_engine_map(maps[0]) if maps else EngineMap(
        (1500, 1900, 2400, 2800, 3200, 3500, 3700, 3850), (15.2, 16.9, 18.6, 18.2, 17.2, 15.4, 9.0, 0.0))
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        curve = predict_shift_curve(tune, engine, n_points=args.points, with_stops=False)
        times.append(time.perf_counter() - t0)
    n = sum(p.segment == "shifting" for p in curve.points)
    print(f"closed form: {n} load points, best {min(times):.3f} s, mean {sum(times) / len(times):.3f} s "
          f"(target < 1 s)")
    if args.full:
        _bench_full(tune, engine, curve, args.points)
    else:
        print("full belt model (BVP): run with --full (one point takes seconds; see docs/tuning.md)")
    if args.fit:
        _bench_fit(tune, engine, curve)


def _bench_full(tune, engine, curve, n_points: int) -> None:
    from dyno.model.params import OperatingPoint
    from dyno.model.solution import solve_point
    from dyno.tuning.tune import model_params_for

    params = model_params_for(tune)
    mid = [p for p in curve.points if p.segment == "shifting"]
    p0, p1 = mid[len(mid) // 2], mid[len(mid) // 2 + 1]
    kw = dict(tol=1e-2, friction_corner=0.2, time_limit_s=60.0)

    def op(p, rpm):
        return OperatingPoint(ratio=p.ratio, primary_speed_rpm=rpm, primary_torque_nm=p.engine_torque_nm,
                              slack_tension_n=None, primary_axial_force_n=p.primary_force_n)

    t0 = time.perf_counter()
    try:
        sol = solve_point(params, op(p0, p0.engine_rpm), **kw)
    except Exception as exc:  # report, do not crash the benchmark
        print(f"full belt model: cold point failed after {time.perf_counter() - t0:.1f} s ({exc})")
        return
    t_cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    try:
        solve_point(params, op(p1, p1.engine_rpm), guess=sol, **kw)
        t_warm = time.perf_counter() - t0
    except Exception as exc:
        print(f"full belt model: warm point failed after {time.perf_counter() - t0:.1f} s ({exc})")
        return
    per_point = 8 * t_warm  # Brent in engine rpm: ~8 belt solves per curve point
    print(f"full belt model: one point cold {t_cold:.1f} s, warm-started next ratio {t_warm:.1f} s -> "
          f"~{n_points * per_point:.0f} s for a {n_points}-point curve (not feasible in < 60 s)")


def _bench_fit(tune, engine, curve) -> None:
    from dyno.tuning.fit import FitRun, MeasuredPoint, NOMINAL, newton_residual_rpm, residual_summary, solver_for

    pts = [MeasuredPoint(p.engine_rpm, p.secondary_rpm, p.secondary_torque_nm)
           for p in curve.points if p.segment == "shifting"][::3]
    solver = solver_for(tune, engine, NOMINAL)
    t0 = time.perf_counter()
    for p in pts:
        newton_residual_rpm(solver, p)
    t_res = time.perf_counter() - t0
    t0 = time.perf_counter()
    residual_summary([FitRun("bench", tune, engine, pts)], NOMINAL)
    t_exact = time.perf_counter() - t0
    print(f"fit: Newton residuals {t_res / len(pts) * 1e3:.1f} ms/point, exact predictions "
          f"{t_exact / len(pts) * 1e3:.1f} ms/point ({len(pts)} points)")


if __name__ == "__main__":
    main()
