#!/usr/bin/env python3
"""Belt-model benchmark: error against run time, stiff/extreme cases, performance figures.

Run:  python bench/bench_model.py [--quick]

Prints (does not assert):
1. error vs run time at four operating points (ratio 0.9 ... 3.5) for each tier
   (capstan, closed form, full BVP with the sharp and the rounded friction corner at
   several tolerances and slip thresholds) against the finest full-model solve at that
   point (tol 1e-4, slip threshold 1e-4 m/s), for the axial forces and the efficiency;
   the PNG docs/img/model-error-vs-time.png;
2. the stiff/extreme-case table (converged and verified, or the
   DidNotConverge message);
3. the performance figures of issue 3: Table 6.1 from no starting solution,
   from a neighbouring solution, a 20-point sweep, closed form per point;
4. the cold-start grid (issue 14): ratio {0.9 ... 3.5} x torque {5, 10, 18} N*m x
   both variants, each solved from no starting solution: time, state (steady /
   gross_slip / failed with its reason), force/moment/power balances, efficiency
   (``--only grid`` for this table alone);
5. the live overlay's latency: a simulated run's points handed to the overlay service at
   their acceptance times, acceptance -> prediction per point, warm vs cold (``--only latency``).
   The UI's own figure (on screen, 1x, whole run): ``python bench/bench_overlay_ui.py``.

``--quick`` (CI's smoke run, about a minute): every table on a much smaller problem -- 1. at Table 6.1 only,
tolerance 1e-2, slip threshold 1e-2, the PNG to a temporary directory (docs/img is left alone); 2. two cases
(a verified one, the gross-slip one); 3. the rounded corner's cold solve, one warm start (from section 1's
cold solve), a 3-point sweep over 1.1..0.9; 4. one ratio and torque, one variant; 5. the speed-hold run's first
point, not solved again cold alone.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dyno.errors import DidNotConverge, GrossSlip  # noqa: E402
from dyno.model import boundary, capstan, closed_form, sweep  # noqa: E402
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


ERROR_POINTS = (  # (label, operating point): ratios 0.9 .. 3.5 at 3400 rpm, 100 N slack
    ("0.9 / 18 N·m", replace(TABLE_6_1_POINT, ratio=0.9)),
    ("1.0 / 18 N·m (Table 6.1)", TABLE_6_1_POINT),
    ("2.0 / 10 N·m", replace(TABLE_6_1_POINT, ratio=2.0, primary_torque_nm=10.0)),
    ("3.5 / 5 N·m", replace(TABLE_6_1_POINT, ratio=3.5, primary_torque_nm=5.0)),
)
PNG = Path(__file__).resolve().parents[1] / "docs" / "img" / "model-error-vs-time.png"


def table_error_vs_time(quick: bool):
    """Every tier x tolerance x slip threshold at each of ERROR_POINTS, against the finest full solve there."""
    print("\n== 1. Error against run time (reference at each point: full BVP, tol 1e-4, v_th 1e-4 m/s; "
          "times are cold solves) ==")
    tols = (1e-2,) if quick else (1e-2, 1e-3, 3e-4)
    slips = (1e-2,) if quick else (1e-2, 1e-3, 1e-4)
    points = [(label, op) for label, op in ERROR_POINTS if op == TABLE_6_1_POINT] if quick else ERROR_POINTS
    rows = []  # (point label, tier, tol, slip, seconds, err F_P, err F_S, err eta)
    base = None
    for label, op in points:
        t0 = time.perf_counter()
        start = solve_point(TABLE_6_1, op, time_limit_s=300)
        if op == TABLE_6_1_POINT:
            base = start
        ref = solve_point(TABLE_6_1, op, tol=1e-4, guess=start, nodes=500, time_limit_s=600)
        print(f"{label}: reference in {time.perf_counter() - t0:.1f} s ({ref.summary['mesh_nodes']} nodes), "
              f"eta {ref.summary['efficiency']['overall']:.4f}, F_P {ref.summary['axial_force_n']['primary']:.0f} N",
              flush=True)
        for name, fn in (("capstan", capstan.capstan_point), ("closed form", closed_form.closed_form_point)):
            n = 50 if quick else 500
            t = time.perf_counter()
            for _ in range(n):
                c = fn(TABLE_6_1, op)
            rows.append((label, name, "-", "-", (time.perf_counter() - t) / n,
                         *errors(c.axial_force_primary_n, c.axial_force_secondary_n, c.efficiency_overall, ref)))
        for corner in (0.0, 0.2):
            tier = "full BVP" if corner == 0 else "full BVP, rounded corner"
            for slip in slips:
                for tol in tols:
                    t = time.perf_counter()
                    try:
                        s = solve_point(TABLE_6_1, op, slip_threshold_m_s=slip, tol=tol, friction_corner=corner,
                                        time_limit_s=120)
                    except Exception as exc:  # noqa: BLE001  (the table reports every outcome)
                        rows.append((label, tier, tol, slip, time.perf_counter() - t, math.nan, math.nan, math.nan))
                        print("  failed:", str(exc)[-160:])
                        continue
                    sm = s.summary
                    rows.append((label, tier, tol, slip, time.perf_counter() - t,
                                 *errors(sm["axial_force_n"]["primary"], sm["axial_force_n"]["secondary"],
                                         sm["efficiency"]["overall"], ref)))
    print(f"\n{'point (ratio / torque)':<26}{'tier':<26}{'tol':>7}{'v_th m/s':>9}{'run s':>10}{'err F_P':>10}"
          f"{'err F_S':>10}{'err eta':>10}")
    for label, name, tol, slip, dt, ep, es, ee in rows:
        print(f"{label:<26}{name:<26}{tol!s:>7}{slip!s:>9}{dt:>10.3g}{ep:>10.2e}{es:>10.2e}{ee:>10.2e}")
    if quick:  # a smoke run's figures are not the documented ones: leave docs/img alone
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            _plot_error_vs_time(rows, Path(tmp) / PNG.name)
    else:
        _plot_error_vs_time(rows)
    return base if base is not None else solve_point()


def _plot_error_vs_time(rows, png: Path = PNG) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except Exception as exc:  # noqa: BLE001  (the table matters more than the plot)
        print("plot skipped:", exc)
        return
    labels = list(dict.fromkeys(r[0] for r in rows))
    fig, axes = plt.subplots(2, 2, figsize=(9, 6.6), sharex=True, sharey=True)
    colours = {1e-2: "tab:red", 1e-3: "tab:orange", 1e-4: "tab:blue"}
    markers = {1e-2: "v", 1e-3: "o", 3e-4: "^"}
    for ax, label in zip(axes.flat, labels):
        for _, name, tol, slip, dt, ep, es, ee in (r for r in rows if r[0] == label):
            if math.isnan(ep):
                continue
            err = max(ep, es, ee, 1e-8)  # worst of the thrust (relative) and efficiency (absolute) errors
            if name in ("capstan", "closed form"):
                ax.loglog(dt, err, "s" if name == "capstan" else "D", color="black" if name == "capstan" else "gray",
                          ms=7, ls="none")
            else:
                ax.loglog(dt, err, markers[tol], color=colours[slip], ms=7, ls="none",
                          mfc="none" if "rounded" in name else colours[slip])
        ax.set_title(f"ratio {label}", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("run time per point [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel("worst error vs finest solve")
    from matplotlib.lines import Line2D

    handles = ([Line2D([], [], marker="s", color="black", ls="none", label="capstan"),
                Line2D([], [], marker="D", color="gray", ls="none", label="closed form")]
               + [Line2D([], [], marker="o", color=c, ls="none", label=f"full, v_th {v:g} m/s")
                  for v, c in colours.items()]
               + [Line2D([], [], marker=m, color="k", mfc="none", ls="none", label=f"tol {t:g}")
                  for t, m in markers.items()]
               + [Line2D([], [], marker="o", color="k", mfc="none", ls="none", label="hollow: rounded corner")])
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8, frameon=False)
    fig.suptitle("belt model: error vs run time (error: max of F_P, F_S relative and efficiency absolute)",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0.08, 1, 0.96))
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=80)
    print(f"PNG: {png} ({png.stat().st_size // 1024} kB)")


QUICK_EXTREMES = ("slip 1e-2 m/s", "slack 10 N")  # a verified case and the gross-slip one


def table_extremes(base, quick: bool = False):
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
    if quick:
        cases = [c for c in cases if c[0] in QUICK_EXTREMES]
    guess = solve_point(guess=base, friction_corner=0.2)
    print(f"{'case':<20}{'result':<12}{'run s':>7}{'resid':>10}{'F_P N':>9}{'F_S N':>9}{'eta':>8}  note")
    for name, params, op, slip in cases:
        t = time.perf_counter()
        try:
            s = solve_point(params, op, slip_threshold_m_s=slip, guess=guess, friction_corner=0.2, time_limit_s=30)
            raw = s.raw
            bc = boundary.make_bc(raw.case)(raw.y[:, 0], raw.y[:, -1], raw.p)
            verified = raw.residual_max <= raw.tol and abs(bc).max() < raw.tol
            sm = s.summary
            print(f"{name:<20}{'verified' if verified else 'UNVERIFIED':<12}{time.perf_counter() - t:>7.1f}"
                  f"{raw.residual_max:>10.2e}{sm['axial_force_n']['primary']:>9.1f}{sm['axial_force_n']['secondary']:>9.1f}"
                  f"{sm['efficiency']['overall']:>8.4f}")
        except (DidNotConverge, GrossSlip) as exc:  # GrossSlip: a state (no steady solution), not a failure
            msg = str(exc)
            what = "GrossSlip" if isinstance(exc, GrossSlip) else "DidNotConv"
            at = msg.find(": ", 30)
            print(f"{name:<20}{what:<12}{time.perf_counter() - t:>7.1f}{'':>36}  {msg[at + 2 if at >= 0 else 0:][:90]}"
                  + (" ... GROSS SLIP (capstan bound reached): beyond the model" if "gross slip" in msg else ""))


def table_performance(base, quick: bool = False):
    print("\n== 3. Performance against the issue-3 targets (ratio = measured / target; < 1 meets it) ==")
    rows = []

    def row(label, seconds, target_s, note=""):
        rows.append((label, seconds, target_s, note))
        print(f"  {label}: {seconds:.3g} s", flush=True)

    if quick:  # the sharp corner's cold solve was timed in section 1 (its start): warm-start from that
        s = base
    else:
        t = time.perf_counter()
        s = solve_point()
        row("Table 6.1 from no starting solution (sharp corner, default)", time.perf_counter() - t, 20.0,
            f"{s.summary['mesh_nodes']} nodes, {s.summary['continuation_steps']} steps")
    t = time.perf_counter()
    sr = solve_point(friction_corner=0.2)
    row("Table 6.1 from no starting solution (rounded corner 0.2)", time.perf_counter() - t, 20.0,
        f"{sr.summary['mesh_nodes']} nodes")
    warm = (("slack 100->105 N", replace(TABLE_6_1_POINT, slack_tension_n=105.0)),
            ("torque 18->19 N*m", replace(TABLE_6_1_POINT, primary_torque_nm=19.0)),
            ("ratio 1.00->1.02", replace(TABLE_6_1_POINT, ratio=1.02)))
    for label, op in warm[:1] if quick else warm:
        t = time.perf_counter()
        w = solve_point(TABLE_6_1, op, guess=s)
        row(f"warm start from the neighbour, {label}", time.perf_counter() - t, 2.0, f"{w.summary['mesh_nodes']} nodes")
    # quick: 3 points near Table 6.1's ratio, the target scaled to the points (60 s for 20)
    n_sweep, span = (3, (1.1, 0.9)) if quick else (20, sweep.DEFAULT_RATIO_RANGE)
    for corner, tol in ((0.2, 1e-2),) if quick else ((0.0, 1e-3), (0.2, 1e-3), (0.2, 1e-2)):
        start = s if corner == 0 else sr
        t = time.perf_counter()
        rows_, _ = sweep.sweep_operating_range(n_sweep, start=start, friction_corner=corner, tol=tol,
                                               ratio_range=span)
        n_ok = sum(bool(r["converged"]) for r in rows_)
        row(f"{n_sweep}-point sweep {span[0]:g}..{span[1]:g}, corner={corner}, tol={tol:g}", time.perf_counter() - t,
            60.0 * n_sweep / 20, f"{n_ok}/{n_sweep} converged")
    n = 500 if quick else 5000
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


def _run_points(plan: str, seed: int, workdir: Path) -> list:
    """(acceptance time s, overlay input) of each point of a headless simulated run (the UI's own inputs)."""
    import json
    import subprocess

    from dyno.model.overlay_inputs import overlay_inputs

    out = workdir / f"{plan}-{seed}"
    subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--seed", str(seed), "--plan", plan,
                    "--out", str(out)], check=True, capture_output=True, timeout=900)
    pts = [d for d in map(json.loads, (out / "documents.jsonl").read_text().splitlines()) if d.get("type") == "point"]
    return [(p["host_t_end_s"], op) for p, (_, op) in zip(pts, (overlay_inputs([p])[0] if overlay_inputs([p])
                                                               else (None, None) for p in pts)) if op is not None]


def table_overlay_latency(plans=("thesis-step", "speed-hold"), seed: int = 0, max_points: int | None = None,
                          cold_alone: bool = True):
    """A run's accepted points handed to the overlay service at their acceptance times (1x): latency per point.

    One background thread as in the UI, a fresh cache (nothing solved before: the first point is cold), and
    each point also solved cold alone for comparison.  Idle gaps between points are skipped when the
    service is idle (nothing it does depends on them), so a 9-minute run replays in well under a minute.
    """
    import statistics
    import tempfile
    from concurrent.futures import ThreadPoolExecutor

    from dyno.model.overlay_service import OverlayService
    from dyno.model.overlay_worker import solve_job

    print("\n== 5. Live overlay latency: each point of a simulated run submitted at its acceptance time (1x), "
          "one background thread, fresh cache ==")
    with tempfile.TemporaryDirectory() as tmp:
        for plan in plans:
            arrivals = _run_points(plan, seed, Path(tmp))[:max_points]
            t_first = arrivals[0][0]
            with ThreadPoolExecutor(1) as pool:
                svc = OverlayService(TABLE_6_1, executor=pool, cache_dir=Path(tmp) / f"cache-{plan}")
                skipped = 0.0
                wall0 = time.monotonic()
                keys = []
                for t_s, op in arrivals:
                    due = wall0 + (t_s - t_first) - skipped
                    while time.monotonic() < due:
                        if svc.idle:
                            skipped += due - time.monotonic()
                            break
                        time.sleep(min(0.01, max(0.0, due - time.monotonic())))
                    keys.append(svc.submit(op))
                svc.wait_idle(600)
            print(f"\n{plan} run (seed {seed}): {len(arrivals)} points over {arrivals[-1][0] - t_first:.0f} s")
            print(f"{'#':>3}{'ratio':>7}{'rpm':>6}{'N·m':>6}{'latency s':>11}{'start':>7}{'steps':>6}"
                  f"{'cold alone s':>14}{'cold steps':>11}")
            lat = []
            for i, ((_, op), k) in enumerate(zip(arrivals, keys)):
                e = svc.entries[k]
                r = e.result
                lat.append(e.latency_s)
                t = time.perf_counter()
                cold, cold_s = {}, math.nan  # (quick: not solved again alone; the service ran the same solve_job)
                if cold_alone:
                    cold, _ = solve_job(TABLE_6_1, svc.entries[k].op, variant="corrected", slip_threshold_m_s=1e-4,
                                        tol=1e-3, time_limit_s=60)
                    cold_s = time.perf_counter() - t
                print(f"{i:>3}{op.ratio:>7.3f}{op.primary_speed_rpm:>6.0f}{op.primary_torque_nm:>6.1f}"
                      f"{e.latency_s:>11.2f}{r.get('start', '-')[:5]:>7}"
                      f"{r.get('steps', 0):>6}{cold_s:>14.2f}{cold.get('steps', 0):>11}")
            print(f"latency per point: median {statistics.median(lat):.2f} s, max {max(lat):.2f} s "
                  f"(max after the first {max(lat[1:], default=math.nan):.2f} s; goal <= 2 s)")


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


def table_grid(variants=("corrected", "as_published"), ratios=GRID_RATIOS, torques=GRID_TORQUES_NM):
    """Cold solve (no starting solution) at every grid point: time, state, balances, efficiency."""
    print("\n== 4. Cold start on the grid: ratio R_S/R_P x primary torque x {slack 100 N, stock tune's clamp at "
          "3400 rpm}, v_th 1e-4 m/s, tol 1e-3 ==")
    print(f"{'variant':<13}{'level':>14}{'ratio':>6}{'torque':>7}{'time s':>8}  {'state':<11}{'force':>9}{'moment':>9}"
          f"{'power':>9}{'eta':>8}  reason")
    worst = {}
    for variant in variants:
        for level in ("slack 100 N", "stock clamp"):
            for ratio in ratios:
                for torque in torques:
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
    ap.add_argument("--quick", action="store_true",
                    help="CI smoke run (about a minute): every table on a few points, the PNG not written to docs/")
    ap.add_argument("--only", choices=("errors", "extremes", "performance", "grid", "latency"), default=None)
    args = ap.parse_args()
    base = None
    grid = dict(variants=("corrected",), ratios=(1.0,), torques=(10.0,)) if args.quick else {}
    latency = dict(plans=("speed-hold",), max_points=1, cold_alone=False) if args.quick else {}
    if args.only == "grid":
        table_grid(**grid)
        return 0
    if args.only == "latency":
        table_overlay_latency(**latency)
        return 0
    if args.only in (None, "errors"):
        base = table_error_vs_time(args.quick)
    if base is None:
        base = solve_point()
    if args.only in (None, "extremes"):
        table_extremes(base, args.quick)
    if args.only in (None, "performance"):
        table_performance(base, args.quick)
    if args.only is None:
        table_grid(**grid)
        table_overlay_latency(**latency)
    return 0


if __name__ == "__main__":
    sys.exit(main())
