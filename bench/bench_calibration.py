"""The calibration wizard on the simulated fixture (``dyno calibrate --sim``): its fit against the physics.

Each seed is a different fixture: the brake-side bridge's gain and offset (±3 %, ±400 counts about the thesis
line) and, with ``--channel input``, the engine cradle's load cell as a run on that seed draws it
(:func:`dyno.sim.world.input_channel_truth`: gain ±1.6 % about 600 counts/N·m, offset, and the trunnion
bearings' friction ``b``, Coulomb on the cell).  The wizard runs its whole procedure (tare, loads up and down
``--repeats`` times, tare) on the virtual clock, through the emulated firmware, bus, reader and poller.

Printed per number of repeats: the fitted gain's error against the true gain (max and rms, %), its normalised
error (z = error / the fit's s.e.), the spread of the repeats' slopes (the reproducibility the wizard shows,
median and max) against the 0.4 % that brings the map-free efficiency's U95 to ~2 pp, and on the input
channel the fitted friction against the true ``b``; with ``--no-friction-term`` the plain line's error too.

    python bench/bench_calibration.py                       # input channel, 8 seeds, 1/2/3/5 repeats
    python bench/bench_calibration.py --channel output --repeats 1,3 --samples 2000
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dyno.analysis.calibration import REPRODUCIBILITY_TARGET_REL  # noqa: E402
from dyno.clock import run  # noqa: E402
from dyno.ui import calibration_wizard  # noqa: E402
from dyno.ui.calibration_feed import run_sim_calibration  # noqa: E402
from dyno.ui.calibration_wizard import CalibrationWizard  # noqa: E402

PLANS = {"output": (0.15, [5, 10, 20, 30, 40]), "input": (0.2, [2, 4, 6, 8, 10])}


def one(channel: str, seed: int, repeats: int, friction_term: bool, samples: int = 500) -> dict:
    radius, masses = PLANS[channel]
    w = CalibrationWizard(channel=channel, repeats=repeats, n_samples=samples)
    assert w.configure(radius, masses) == []
    orig = calibration_wizard.fit_repeats
    if not friction_term:  # the plain line, for comparison
        calibration_wizard.fit_repeats = lambda *a, **k: orig(*a, **{**k, "friction_term": False})
    try:
        rig = run(run_sim_calibration(w, seed=seed), virtual=True)
    finally:
        calibration_wizard.fit_repeats = orig
    fx, f = rig.fixture, w.fit
    if f is None:
        return {"refused": w.rejection}
    true = fx.true_input_gain_counts_per_nm if channel == "input" else fx.true_gain_counts_per_nm
    out = {"err": f.slope_counts_per_nm / true - 1.0, "z": (f.slope_counts_per_nm - true) / f.slope_se_counts_per_nm,
           "repro": w.repro.rel_sd, "refused": w.rejection}
    if channel == "input":
        out["b_true"] = fx.cradle_bearing_nm
        out["b_fit"] = f.friction_nm
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--channel", choices=tuple(PLANS), default="input")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--repeats", default="1,2,3,5")
    ap.add_argument("--samples", type=int, default=500, help="ADC samples kept per step (default 500)")
    ap.add_argument("--no-friction-term", action="store_true", help="also the plain line (input channel)")
    ap.add_argument("--quick", action="store_true", help="CI smoke run: 2 seeds, 2 repeats, 150 samples a step")
    a = ap.parse_args(argv)
    if a.quick:
        a.seeds, a.repeats, a.samples = 2, "2", 150
    print(f"dyno calibrate --sim --channel {a.channel} --samples {a.samples}: {a.seeds} seeds; target reproducibility "
          f"{100 * REPRODUCIBILITY_TARGET_REL:.1f} %")
    for reps in (int(x) for x in a.repeats.split(",")):
        for friction in ((True, False) if a.no_friction_term and a.channel == "input" else (True,)):
            t0 = time.perf_counter()
            rs = [one(a.channel, s, reps, friction, a.samples) for s in range(a.seeds)]
            ok = [r for r in rs if "err" in r]
            if not ok:
                print(f"repeats {reps}: no calibration completed ({len(rs)} refused)", flush=True)
                return 1
            errs = [100 * r["err"] for r in ok]
            line = (f"repeats {reps}{'' if friction else ' (plain line)'}: gain error max {max(map(abs, errs)):.3f} %, "
                    f"rms {math.sqrt(statistics.fmean(e * e for e in errs)):.3f} %, mean {statistics.fmean(errs):+.3f} %, "
                    f"z sd {statistics.pstdev([r['z'] for r in ok]):.2f}")
            if reps > 1:
                rep = sorted(100 * r["repro"] for r in ok)
                line += (f"; reproducibility median {statistics.median(rep):.3f} %, max {rep[-1]:.3f} % "
                         f"({sum(x <= 100 * REPRODUCIBILITY_TARGET_REL for x in rep)}/{len(rep)} <= the target)")
            if a.channel == "input" and friction:
                db = [r["b_fit"] - r["b_true"] for r in ok]
                line += f"; friction error max {max(map(abs, db)):.4f} N·m (b {min(r['b_true'] for r in ok):.3f}…{max(r['b_true'] for r in ok):.3f})"
            refused = [r["refused"] for r in rs if r["refused"]]
            line += f"; refused {len(refused)}; {time.perf_counter() - t0:.0f} s"
            print(line, flush=True)
            for why in refused[:3]:
                print(f"  refused: {why}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
