"""The speed hold on the simulated rig through the real-rig output code (relay settle of rig.toml):
5 % setpoint steps over seeds 1-10 settle with <= 3 % overshoot and <= 0.3 % sd, within the plan's
+-0.75 % in <= 3 s every time and within +-0.5 % in <= 2 s for most (one minimum pulse moves the
speed ~1 % of the setpoint: a step whose last pulse lands just past 0.5 % waits for the brake's fade
to bring it back, docs/control.md); and holding against the release end stop does not wind up (the
next setpoint is reached as fast as from contact).  Simulated time: deterministic, not a wall-clock
assertion.  (A single seed's settle time is luck: which pulse ends the approach.)"""

import asyncio
import statistics

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.sim.rig_params import RigParams
from dyno.control.plans import speed_hold as sh
from dyno.control.api import State, TestPlan as Plan
from dyno.control.outputs import STOP
from dyno.control.api import SpeedHold
from dyno.control.plans.speed_hold import find_contact


def _trace(ctx, sp: float, seconds: float):
    async def go():
        t0, out = ctx.now(), []
        while ctx.now() - t0 < seconds:
            await ctx.sleep(0.05)
            out.append((ctx.now() - t0, ctx.read.secondary_rpm(0.1)))
        return out
    return go()


def _figures(trace, sp: float, start: float) -> dict:
    outside = [t for t, r in trace if abs(r - sp) > 0.005 * sp]
    outside_plan = [t for t, r in trace if abs(r - sp) > sh.SpeedHoldPlan.tolerance_rel * sp]
    beyond = [(r - sp) * (1 if sp > start else -1) for _, r in trace]
    return {"settle_s": max(outside) if outside else 0.0, "overshoot_pc": 100 * max(0.0, max(beyond)) / sp,
            "settle_plan_s": max(outside_plan) if outside_plan else 0.0,
            "sd_pc": 100 * statistics.pstdev(r for t, r in trace if t > trace[-1][0] - 3.0) / sp}


def _hold_run(out_dir, seed: int, end_stop: bool) -> dict:
    found = {}

    async def runner(ctx, params=None):
        ctx.phase(State.STEP, "test: contact")
        no_load = ctx.read.secondary_rpm(1.0)
        t_c = ctx.now()
        assert await find_contact(ctx)
        found["contact_s"] = ctx.now() - t_c  # the free travel from the released end to the pads
        await ctx.hold(SpeedHold(3000.0, wait=False))  # the engine's hold loop, the rig's [control] gains
        found["from_contact"] = _figures(await _trace(ctx, 3000.0, 12.0), 3000.0, no_load)
        for sp in STEPS_RPM:
            start = ctx.read.secondary_rpm(0.1)
            await ctx.hold(SpeedHold(sp, wait=False))
            found[sp] = _figures(await _trace(ctx, sp, 8.0), sp, start)
        if end_stop:
            # An unreachable setpoint above the no-load speed: full release into the end stop for 12 s.
            await ctx.hold(SpeedHold(1.3 * no_load, wait=False))
            await ctx.sleep(12.0)
            law = ctx._holds.law  # (white box: the running law's state)
            found["owed_s"], found["integral"] = law.owed_s, law.integral
            start = ctx.read.secondary_rpm(0.1)
            await ctx.hold(SpeedHold(3000.0, wait=False))
            trace = await _trace(ctx, 3000.0, 12.0)
            found["after_end_stop"] = _figures(trace, 3000.0, start)
            found["bite_s"] = next(t for t, r in trace if r < 0.99 * start)  # the pads slow the secondary again
        ctx.brake(STOP)  # (ends the hold)
        ctx.phase(State.SETTLE, "test")
        ctx.phase(State.DONE, "test done")

    # the thesis rig as specified (RigParams(ideal=True): its engine exactly its map, the reference
    # day): these are the hold's figures on that plant; a seed's own engine (dyno.sim.world, up to
    # ~20 % down on a hot day at altitude) changes the plant's gain, which is not what this checks.
    # The test's own mode comes with the run's spec.
    r = run_test(RunSpec(sim=True, seed=seed, plan=Plan(mode="test-hold"), mock_pins=True,
                            runners={"test-hold": runner}, out_dir=out_dir / "run", sim_params=RigParams(ideal=True)))
    assert r["state"] in ("done", "aborted") and not [a for a in r["aborts"] if a["cause"] != "no_points"]
    return found


STEPS_RPM = (3150.0, 2992.5)  # +5 %, -5 %
SEEDS = range(1, 11)


@pytest.fixture(scope="module")
def hold_figures(tmp_path_factory):
    return _hold_run(tmp_path_factory.mktemp("hold"), 1, end_stop=True)


@pytest.fixture(scope="module")
def step_figures(tmp_path_factory, hold_figures):
    runs = [hold_figures] + [_hold_run(tmp_path_factory.mktemp(f"hold{seed}"), seed, end_stop=False)
                             for seed in SEEDS if seed != 1]
    return {sp: [run[sp] for run in runs] for sp in STEPS_RPM}


@pytest.mark.parametrize("sp", STEPS_RPM)
def test_five_percent_steps_settle_within_issue_figures_over_seeds(step_figures, sp):
    figs = step_figures[sp]
    for f in figs:
        assert f["overshoot_pc"] <= 3.0 and f["sd_pc"] <= 0.3, f
        assert f["settle_plan_s"] <= 3.0, f  # within the plan's own +-0.75 % "at the setpoint" (measured <= 2.45 s)
    settle = sorted(f["settle_s"] for f in figs)
    assert statistics.median(settle) <= 2.0, settle
    assert sum(t <= 2.0 for t in settle) >= 6, settle  # of 10: measured 7 for each step


def test_no_windup_at_the_release_end_stop(hold_figures):
    # 12 s of full-release command into the end stop left nothing owed and nothing integrated ...
    assert abs(hold_figures["owed_s"]) <= 0.05 and hold_figures["integral"] == 0.0
    back, fresh = hold_figures["after_end_stop"], hold_figures["from_contact"]
    # ... so on the new setpoint the actuator drives at once: the pads bite again after the free travel
    # (what the contact search took at full speed) plus the speed window's and the loop's delays, and
    # overshoot no more than from the contact point.  A wound-up hold would first unwind what it stored.
    # (The settle time itself is not compared: from 4,800 to 3,000 rpm the path crosses the CVT's shift,
    # whose hysteresis makes the 0.5 % band's last exit differ by seconds between two equal runs.)
    assert hold_figures["bite_s"] <= hold_figures["contact_s"] + 0.35, hold_figures
    assert back["overshoot_pc"] <= fresh["overshoot_pc"] + 3.0, (back, fresh)
