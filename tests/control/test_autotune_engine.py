"""Auto-tune of the engine-speed hold on the simulated rig (through the real output code, mock pins), at
heavy load (the secondary first held at 3,000 rpm): on the logs' plant the engine sits inside the CVT's shift
there, and the identification refuses with the physical reason (a pulse moves the secondary, not the engine)
on three seeds and on a brake twice as stiff; the hold with rig.toml's kp stays near its setpoint.
Simulated time: deterministic, not a wall-clock assertion."""

import statistics
from dataclasses import replace

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.control.api import EngineHold, SpeedHold
from dyno.control.holds import gains_for
from dyno.control.outputs import STOP
from dyno.control.plans import speed_hold as sh
from dyno.control.plans.autotune import MAX_SHIFT_SHARE, MAX_SPREAD, identify_gain
from dyno.control.plans.steps import probe_load_raises
from dyno.control.api import State, TestPlan as Plan
from dyno.control.plans.speed_hold import find_contact
from dyno.sim.rig_params import RigParams


def _figures(trace, sp: float, start: float) -> dict:
    outside = [t for t, x in trace if abs(x - sp) > 0.005 * sp]
    beyond = [(x - sp) * (1 if sp > start else -1) for _, x in trace]
    outside_plan = [t for t, x in trace if abs(x - sp) > sh.SpeedHoldPlan.tolerance_rel * sp]
    return {"settle_s": max(outside) if outside else 0.0, "overshoot_pc": 100 * max(0.0, max(beyond)) / sp,
            "settle_plan_s": max(outside_plan) if outside_plan else 0.0,
            "sd_pc": 100 * statistics.pstdev(x for t, x in trace if t > trace[-1][0] - 3.0) / sp}


async def _trace(ctx, seconds: float, window_s: float):
    t0, out = ctx.now(), []
    while ctx.now() - t0 < seconds:
        await ctx.sleep(0.05)
        out.append((ctx.now() - t0, ctx.read.engine_rpm(window_s)))
    return out


def _tune_and_step(tmp_path, seed: int, params=None) -> dict:
    found = {}

    async def runner(ctx, params=None):
        ctx.phase(State.STEP, "test: contact")
        assert await find_contact(ctx)
        await ctx.hold(SpeedHold(3000.0, wait=False))  # heavy load: where the engine-hold plan starts
        await ctx.sleep(8.0)
        ctx.brake(STOP)
        raises = found["raises"] = await probe_load_raises(ctx, "engine")  # which way more brake moves the engine
        sp0 = ctx.read.engine_rpm(1.0)
        base = gains_for(ctx.config.control, "engine")
        found["identify"] = await identify_gain(ctx, "engine", sp0, base, load_raises=raises)
        gains = replace(base, kp=found["identify"]["kp_identified"]) if found["identify"]["ok"] else base
        found["kp"] = gains.kp
        await ctx.hold(EngineHold(sp0, load_raises=raises, gains=gains, wait=False))
        await _trace(ctx, 8.0, gains.speed_window_s)
        found["steps"] = []
        for sp in (sp0 * 1.05, sp0):
            start = ctx.read.engine_rpm(gains.speed_window_s)
            await ctx.hold(EngineHold(sp, load_raises=raises, gains=gains, wait=False))
            found["steps"].append(_figures(await _trace(ctx, 8.0, gains.speed_window_s), sp, start))
        ctx.brake(STOP)
        ctx.phase(State.SETTLE, "test")
        ctx.phase(State.DONE, "test done")

    # the test's own mode comes with the run's spec
    r = run_test(RunSpec(sim=True, seed=seed, plan=Plan(mode="test-engine-tune"), mock_pins=True,
                            runners={"test-engine-tune": runner}, out_dir=tmp_path / "run", sim_params=params))
    assert not [a for a in r["aborts"] if a["cause"] != "no_points"], r["aborts"]
    return found


CASES = [(1, False), (2, False), (3, False), (1, True)]  # (seed, stiff brake)


@pytest.fixture(scope="module")
def tunes(tmp_path_factory):
    stiff_params = replace(RigParams(), brake_spring_rate_n_per_mm=13.0)
    return {(seed, stiff): _tune_and_step(tmp_path_factory.mktemp(f"tune{seed}{stiff}"), seed,
                                          stiff_params if stiff else None) for seed, stiff in CASES}


@pytest.mark.parametrize("seed, stiff", CASES)
def test_engine_identification_refused_where_the_cvt_shifts(tunes, seed, stiff):
    """On the logs' plant the CVT shifts at a near-flat engine speed: at 3,000 rpm on the secondary the engine
    sits inside the shift, where the CVT, not the brake, sets its speed.  Without the shift's friction a brake
    pulse moved the secondary ~20x as much as the engine (relative; 19-24x on seeds 1-3) and a kp scaled to the
    engine's small gain rang (a 5 % step overshot 9-10 %).  With the sheaves' friction (dyno.sim.cvt_friction:
    a dead band in the shift balance) the CVT sticks through some pulses and slips on others: the secondary
    still moves 3-6x as much as the engine, and the pulses' engine gains disagree (e.g. 0.02 /s on the first,
    0.12 /s on the next three).  Either way the engine's speed is not the brake's to set here, so the
    identification refuses, says why, and leaves rig.toml's kp in place -- on either brake."""
    f = tunes[(seed, stiff)]
    ident = f["identify"]
    assert ident["variable"] == "engine" and ident["kp_key"] == "kp_engine" and ident["kp_before"] == 3.0
    assert not ident["ok"] and not ident["applied"] and f["kp"] == 3.0, ident
    shifting = ident["secondary_over_engine"] > MAX_SHIFT_SHARE
    assert shifting or ident["spread"] > MAX_SPREAD, ident
    assert ident["reason"].startswith("the CVT shifts here" if shifting else "pulses disagree"), ident


def test_the_engine_hold_stays_near_its_setpoint_inside_the_shift(tunes):
    """With rig.toml's kp the engine hold inside the shift neither runs away nor rings: after the step back to
    the starting speed the engine's sd over the last 3 s stays small (measured 0.20 %), though the 5 % step up is
    never reached (the CVT holds the engine: the brake moves the secondary instead)."""
    for case in CASES:
        up, back = tunes[case]["steps"]
        assert back["sd_pc"] <= 0.3 and back["overshoot_pc"] <= 3.0, (case, back)


def test_identify_engine_step_as_a_real_process(tmp_path):
    """A plan file with the engine's identify step, through `dyno run --sim --mock-pins --json`: what the
    identification found (here: refused, the CVT shifting) is recorded with the run, and the engine hold that
    follows runs on."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    plan = tmp_path / "engine-tune.toml"
    plan.write_text('schema = "dyno.plan/1"\nname = "engine-tune"\nmode = "steps"\n'
                    '[test]\nmeasure_s = 2.0\ntarget_efficiency_ci95 = 0.01\nmax_measure_s = 6.0\n'
                    '[[step]]\nkind = "contact"\n'
                    '[[step]]\nkind = "hold"\nvariable = "secondary"\nsetpoint = 3000.0\nmeasure = false\n'
                    '[[step]]\nkind = "identify"\nvariable = "engine"\nsetpoint = 2980.0\n'
                    '[[step]]\nkind = "hold"\nvariable = "engine"\nsetpoint = 2930.0\n')
    proc = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--mock-pins", "--json", "--plan", str(plan),
                           "--out", str(tmp_path / "run")], capture_output=True, text=True, timeout=180,
                          cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(root)))
    assert proc.returncode == 0, proc.stderr
    d = json.loads(proc.stdout)
    assert d["state"] == "done" and len(d["points"]) == 1
    docs = [json.loads(line) for line in (tmp_path / "run" / "documents.jsonl").read_text().splitlines()]
    (ident,) = [x for x in docs if x["type"] == "identify"]
    # refused inside the shift (the test above), recorded with the run; the hold that follows keeps rig.toml's kp
    assert not ident["ok"] and not ident["applied"] and ident["variable"] == "engine"
    assert ident["reason"].startswith("the CVT shifts here"), ident
    assert abs(d["points"][0]["rpm_primary"] - 2930.0) <= 0.02 * 2930.0
