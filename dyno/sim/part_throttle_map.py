"""Write the simulated engine's part-throttle map (a SYNTHETIC map, generated from the sim's model).

    python -m dyno.sim.part_throttle_map [--out CSV] [--throttles 0.3,0.4,...]

The simulated engine follows its full-throttle map exactly and, at part throttle, the governor
set-speed model of :mod:`dyno.sim.engine`.  This script tabulates that model as a
``throttle,rpm,torque_nm`` CSV (docs/analysis.md, "Part throttle"), the same arrangement as the
full-throttle map: the host reads the CSV grid with its own PCHIP and never calls the sim.  A real
rig needs a part-throttle map measured on an engine dyno; this file is for the simulated rig only.

Knots per throttle ``u``: the full map's knots below the governor band, every 10 rpm over the last
200 rpm before the band and across it (closer just past the band's start, a kink), and the end where the net torque falls to 0 (beyond it the
engine makes no power: no efficiency).  The full-throttle rows are the full map's own rows, so the
full-throttle curve is the same map, knot for knot.  It prints the largest torque error of the
host's interpolation of these knots against the model.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from dyno.sim.physics import RigModel
from dyno.sim.rig_params import RigParams, resolve_map_path

DEFAULT_OUT = Path(__file__).resolve().parents[2] / "calibration" / "engine_maps" / "baja-10hp-representative-part-throttle.csv"
DEFAULT_THROTTLES = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
DENSE_RPM = 10.0
DENSE_SPAN_RPM = 200.0
KINK_STEPS_RPM = (0.1, 0.3, 1.0, 3.0)


def curve_knots(engine, u: float) -> tuple[np.ndarray, np.ndarray]:
    """(rpm, torque_nm) knots of the model's net torque at throttle ``u``, up to where it reaches 0."""
    m = engine.map

    def torque(n: float) -> float:
        return engine.torque_nm(n, u, True)

    n_set = engine.set_speed_rpm(u)
    knee = n_set - engine.droop_rpm  # fuel fraction 1 below this (the full map)
    hi = min(n_set, m.rpm_max)
    if torque(hi) > 0.0:
        n0 = hi
    else:
        n0 = brentq(torque, max(m.rpm_min, knee), hi, xtol=1e-9)
    start = max(m.rpm_min, min(knee, n0) - DENSE_SPAN_RPM)
    rpm = {float(x) for x in m.rpm if x < start}
    rpm |= {float(x) for x in np.arange(start, n0, DENSE_RPM)}
    if m.rpm_min < knee < n0:
        # the kink where the governor starts to cut fuel: PCHIP gives a kink knot a slope near the
        # gentler side's, so the first interval after it must be short (its error ~ slope jump x h / 4)
        rpm -= {r for r in rpm if abs(r - knee) < 0.5 * DENSE_RPM}
        rpm |= {float(knee)} | {float(knee + s * d) for d in KINK_STEPS_RPM for s in (-1, 1)}
    rpm = np.array(sorted(r for r in rpm if r < n0 - 0.1) + [n0])
    t = np.array([max(0.0, torque(n)) for n in rpm])
    t[-1] = 0.0 if n0 < hi or torque(n0) <= 0.0 else t[-1]
    return rpm, t


def write_map(out: Path, throttles=DEFAULT_THROTTLES) -> float:
    """Write the CSV; returns the host interpolation's largest torque error vs the model, N·m."""
    from dyno.analysis.engine_map import load_engine_map

    # the nominal engine (its map exactly, the reference day): the shipped map is the representative
    # engine's, not one seed's (dyno.sim.world)
    model = RigModel(RigParams(ideal=True))
    eng, p = model.engine, model.params
    src = resolve_map_path(p.engine_map_path)
    full_rows = [ln for ln in Path(src).read_text().splitlines()
                 if ln.strip() and not ln.startswith("#")][1:]
    lines = ["# SYNTHETIC part-throttle engine map, GENERATED from the simulator's engine model",
             "# (python -m dyno.sim.part_throttle_map): NOT a measurement. Full throttle (throttle 1) is",
             f"# {Path(src).name} row for row; part throttle is the sim's governor set-speed model",
             f"# (idle {p.engine_idle_rpm:g} + {p.engine_idle_offset_rpm:g} rpm, droop {p.engine_governor_droop_rpm:g} rpm,",
             f"# friction {p.engine_friction_nm:g}..{p.engine_friction_at_3600_rpm_nm:g} N*m). A real rig needs a part-throttle",
             "# map measured on an engine dyno. Columns: throttle fraction, engine rpm, net brake torque N*m.",
             # the host's stated uncertainty of this map (dyno.analysis.engine_map), for the host's reading only
             f"# stated_u_rel = 0.10 | as {Path(src).name} at full throttle (representative, not measured); "
             "the part-throttle curves are synthetic and no better",
             "# measured_on_this_engine = no",
             "throttle,rpm,torque_nm"]
    lines += [f"1,{r.strip()}" for r in full_rows]
    for u in sorted(throttles, reverse=True):
        rpm, t = curve_knots(eng, u)
        lines += [f"{u:g},{n:.4f},{x:.6f}" for n, x in zip(rpm, t)]
    from dyno.fileio import write_atomic

    write_atomic(out, "\n".join(lines) + "\n")  # (a reader never sees half a map)
    host = load_engine_map(out)
    worst = 0.0
    for u in throttles:
        c = host.at_throttle(u)
        n = np.linspace(c.rpm_min, c.rpm_max, 4000)
        err = np.abs(np.asarray(c.torque_nm(n)) - np.array([max(0.0, eng.torque_nm(x, u, True)) for x in n]))
        worst = max(worst, float(err.max()))
    return worst


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m dyno.sim.part_throttle_map", description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--throttles", default=",".join(f"{u:g}" for u in DEFAULT_THROTTLES),
                    help="comma-separated throttle fractions in (0, 1)")
    a = ap.parse_args(argv)
    try:
        throttles = [float(x) for x in a.throttles.split(",")]
    except ValueError:
        throttles = [math.nan]
    if not all(0.0 < u < 1.0 for u in throttles):
        print(f"--throttles: expected comma-separated fractions in (0, 1), got {a.throttles!r}", file=sys.stderr)
        return 2
    worst = write_map(a.out, throttles)
    print(f"wrote {a.out}: throttles {', '.join(f'{u:g}' for u in sorted(throttles))} + 1; "
          f"host PCHIP vs model: max torque error {worst:.2e} N*m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
