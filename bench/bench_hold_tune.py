#!/usr/bin/env python3
"""Step responses of the torque hold and the engine-speed hold on the simulated rig, per kp and seed.

For each variable the rig is brought to a standard operating point (contact; torque: hold 16 N·m;
engine: the secondary held at 3,000 rpm -- heavy load, the CVT in low -- then the engine held where it
is), then the setpoint is stepped by +5 % and -5 % and each step's figures printed as in the speed
hold's (bench_test_time.py): the time after which the held value stays within +-0.5 % of the setpoint,
the overshoot (% of the setpoint) and the standard deviation over the last 3 s (% of the setpoint),
each value read through the hold's own window (torque 0.2 s, speeds 0.15 s).  With ``--identify``,
the auto-tune's identification runs first at the operating point and its kp is used.

Through the real-rig output code on mock pins (rig.toml's relay settle honoured).

    python bench/bench_hold_tune.py [--variable torque|engine] [--seeds 1,2,3] [--kp 1.0,2.0] [--identify] [--quick]

``--quick`` (CI's smoke run): seed 1 only.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dyno.control.api import Hold, SpeedHold  # noqa: E402
from dyno.control.holds import gains_for  # noqa: E402
from dyno.control.outputs import STOP  # noqa: E402
from dyno.session.root import RunSpec, run_test  # noqa: E402
from dyno.control.api import State, TestPlan  # noqa: E402
from dyno.control.plans.speed_hold import find_contact  # noqa: E402

OPERATING = {"torque": 16.0, "engine": None}  # engine: where it is with the secondary at 3,000 rpm
SIGN = {"torque": -1.0, "engine": -1.0}  # engine at heavy load: more brake raises it (the CVT back-shifts)


def figures(trace, sp: float, start: float) -> dict:
    outside = [t for t, x in trace if abs(x - sp) > 0.005 * sp]
    beyond = [(x - sp) * (1 if sp > start else -1) for _, x in trace]
    return {"settle_s": max(outside) if outside else 0.0, "overshoot_pc": 100 * max(0.0, max(beyond)) / sp,
            "sd_pc": 100 * statistics.pstdev(x for t, x in trace if t > trace[-1][0] - 3.0) / sp}


async def trace_of(ctx, variable: str, window_s: float, seconds: float):
    t0, out = ctx.now(), []
    while ctx.now() - t0 < seconds:
        await ctx.sleep(0.05)
        out.append((ctx.now() - t0, ctx.read.value(variable, window_s)))
    return out


def run(variable: str, seed: int, kp: float | None, identify: bool, tmp: Path, params=None,
        deadband: float | None = None) -> dict:
    found: dict = {}

    async def runner(ctx, params=None):
        ctx.phase(State.STEP, "bench: contact")
        assert await find_contact(ctx)
        if variable == "engine":  # into the heavy-load region first, as the engine-hold plan does
            await ctx.hold(SpeedHold(3000.0, wait=False))
            await ctx.sleep(8.0)
            ctx.brake(STOP)
        sp0 = OPERATING[variable] or ctx.read.value(variable, 1.0)
        if identify:
            from dyno.control.plans.autotune import identify_gain

            res = await identify_gain(ctx, variable, sp0, gains_for(ctx.config.control, variable),
                                      load_raises=SIGN[variable] < 0)
            found["identify"] = res
        gains = gains_for(ctx.config.control, variable)
        if identify and found["identify"]["ok"]:
            gains = replace(gains, kp=found["identify"]["kp_identified"])
        if kp is not None:
            gains = replace(gains, kp=kp)
        if deadband is not None:
            gains = replace(gains, deadband_rel=deadband)
        found["kp"] = gains.kp
        await ctx.hold(Hold(variable, sp0, gains=gains, load_raises=SIGN[variable] < 0, wait=False))
        await trace_of(ctx, variable, gains.speed_window_s, 8.0)
        steps = []
        for sp in (sp0 * 1.05, sp0):
            start = ctx.read.value(variable, gains.speed_window_s)
            await ctx.hold(Hold(variable, sp, gains=gains, load_raises=SIGN[variable] < 0, wait=False))
            tr = await trace_of(ctx, variable, gains.speed_window_s, 8.0)
            steps.append({"from": start, "to": sp, **figures(tr, sp, start)})
        found["steps"] = steps
        # the noise floor: the brake frozen where the hold put it, the same reading's sd over 3 s
        ctx.brake(STOP)  # (ends the hold: the brake stays where it put it)
        await ctx.sleep(1.0)
        tr = await trace_of(ctx, variable, gains.speed_window_s, 3.0)
        found["frozen_sd_pc"] = 100 * statistics.pstdev(x for _, x in tr) / sp0
        tr = await trace_of(ctx, variable, 1.0, 3.0)
        found["frozen_sd_1s_pc"] = 100 * statistics.pstdev(x for _, x in tr) / sp0
        ctx.phase(State.SETTLE, "bench")
        ctx.phase(State.DONE, "bench done")

    r = run_test(RunSpec(sim=True, seed=seed, plan=TestPlan(mode="bench-hold"), mock_pins=True,
                            runners={"bench-hold": runner},  # the bench's own mode, with the run's spec
                            out_dir=tmp / f"{variable}-{seed}-{kp}-{identify}", sim_params=params))
    found["aborts"] = [a for a in r["aborts"] if a["cause"] != "no_points"]
    return found


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--variable", default="torque", choices=("torque", "engine"))
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--kp", default="", help="comma-separated kp values (default: rig.toml's)")
    ap.add_argument("--identify", action="store_true")
    ap.add_argument("--deadband", type=float, default=None, help="the hold's dead band (default: rig.toml's)")
    ap.add_argument("--stiff", action="store_true", help="a brake spring twice as stiff (13 N/mm)")
    ap.add_argument("--quick", action="store_true", help="CI smoke run: seed 1 only")
    a = ap.parse_args()
    if a.quick:
        a.seeds = "1"
    params = None
    if a.stiff:
        from dyno.sim.rig_params import RigParams

        params = replace(RigParams(), brake_spring_rate_n_per_mm=13.0)
    kps = [float(x) for x in a.kp.split(",") if x] or [None]
    print(f"| variable | seed | kp | step | settle s (±0.5 %) | overshoot % | sd % |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for kp in kps:
            for seed in (int(s) for s in a.seeds.split(",")):
                f = run(a.variable, seed, kp, a.identify, Path(tmp), params, a.deadband)
                if f.get("identify"):
                    i = f["identify"]
                    print(f"<!-- identify seed {seed}: ok={i['ok']} g={i.get('gain_rel_per_s', float('nan')):.3f} "
                          f"spread={i.get('spread', float('nan')):.2f} kp={i.get('kp_identified', float('nan')):.2f} "
                          f"{i.get('reason', '')} -->")
                for s in f.get("steps", []):
                    print(f"| {a.variable} | {seed} | {f['kp']:.2f} | {s['from']:.1f} → {s['to']:.1f} | "
                          f"{s['settle_s']:.2f} | {s['overshoot_pc']:.2f} | {s['sd_pc']:.3f} |")
                print(f"<!-- seed {seed} kp {f['kp']:.2f}: brake frozen, sd of the hold's reading "
                      f"{f['frozen_sd_pc']:.3f} % (1 s mean: {f['frozen_sd_1s_pc']:.3f} %) -->")
                if f["aborts"]:
                    print(f"<!-- aborts: {f['aborts']} -->")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
