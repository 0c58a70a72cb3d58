"""Auto-tune of the speed holds (secondary or engine rpm): identify the plant's gain with brake pulses,
scale ``kp`` to it.

At a held speed the brake is frozen, then pulsed at full speed for ``pulse_s`` (APPLY, then RELEASE
back), and the speed read before and 1.5 s after each pulse (long after the ~0.3 s lag)::

    g = |Δn| / n / pulse_s          (relative speed change per second of full-speed travel)

The loop's gain ``kp·g`` is what sets its damping, so ``kp = LOOP_GAIN_PER_S[variable] / g``; each is
the simulated rig's tuned loop through the real output code (secondary: kp = 12, with its 0.5 s lead, on
g ≈ 0.38 /s near 3,000 rpm; the lead is kept as rig.toml gives it; engine at heavy load: the kp that
settles a 5 % step fastest, ``bench/bench_hold_tune.py``).
The result is used only if the pulses agree (spread ≤ ``MAX_SPREAD``) and ``kp`` lands in a sane range;
otherwise the rig.toml gain stays and an ``identify`` document says why.  Either way it is recorded with
the run.  The torque hold has none: its gauge reading's own scatter (sd ~2 % of the setpoint over the
hold's 0.2 s window, brake frozen) is larger than the step figures it would be tuned to (docs/control.md).
"""

from __future__ import annotations

import math
import statistics
from dataclasses import replace

from dyno.control.api import Hold, PlanContext
from dyno.control.hold_law import HoldGains
from dyno.control.outputs import APPLY, RELEASE, STOP

# The loop gains kp·g each hold was tuned to on the simulated rig (bench/bench_hold_tune.py, the engine at heavy
# load; bench/bench_test_time.py, the secondary): a narrow window (±5 %), so the identification must be repeatable.
ENGINE_LOOP_GAIN = 0.82
SECONDARY_LOOP_GAIN = 4.5
LOOP_GAIN_PER_S = {"secondary": SECONDARY_LOOP_GAIN, "engine": ENGINE_LOOP_GAIN}
#: the rig.toml [control] key each variable's identified kp replaces
KP_KEY = {"secondary": "kp_speed", "engine": "kp_engine"}
MAX_SPREAD = 0.5  # (max - min) / mean of the pulses' gains
REACH_ATTEMPTS = 3  # holds tried before pulsing: kp, kp/2, kp/4 (a too-high kp rings instead of holding)
KP_RANGE = (0.3, 30.0)
# The engine's hold is the brake's only where the CVT sits at a stop: there the secondary follows the engine
# (a relative move ~1x the engine's); inside the shift the CVT holds the engine and a pulse moves the secondary
# instead (measured ~10x and more on the logs' plant).
MAX_SHIFT_SHARE = 3.0


async def _pulse(ctx: PlanContext, direction: int, pulse_s: float) -> None:
    ctx.brake(direction)
    try:
        await ctx.sleep(pulse_s)
    finally:
        ctx.brake(STOP)


async def identify_gain(ctx: PlanContext, variable: str, setpoint: float, base: HoldGains, *,
                        load_raises: bool = False, pulse_s: float = 0.2, repeats: int = 2) -> dict:
    """Identify ``g`` of ``variable`` (secondary | engine rpm) at ``setpoint`` while holding it with ``base``
    (``load_raises``: more brake raises the speed, the engine while the CVT back-shifts).  Returns what was
    found: ``ok``, ``kp_identified`` (the kp for ``base``'s loop gain), the pulses' gains, and why not."""
    if variable not in LOOP_GAIN_PER_S:
        raise ValueError(f"no auto-tune for {variable!r}: one of {', '.join(LOOP_GAIN_PER_S)}")
    gains = []
    try:
        # The hold must settle before the plant can be pulsed.  The gain being tuned may be too high
        # for this plant (a stiffer brake: the loop rings instead of holding), so halve it and retry.
        reached, hold_kp = False, base.kp
        for attempt in range(REACH_ATTEMPTS):
            hold_kp = base.kp / 2 ** attempt
            held = await ctx.hold(Hold(variable, setpoint, in_band_s=1.0, max_approach_s=10.0,
                                       load_raises=load_raises, gains=replace(base, kp=hold_kp)))
            if held.reached:
                reached = True
                break
            ctx.brake(STOP)
        if not reached:
            result = {"ok": False, "reason": f"could not hold {setpoint:.0f} rpm to identify (kp {base.kp:g} "
                                             f"down to {hold_kp:g})"}
        else:
            ctx.brake(STOP)  # the hold ends: the brake stays where it put it
            await ctx.sleep(1.0)
            shares = []  # the secondary's relative move over the engine's, per pulse (engine only)
            for _ in range(repeats):
                for direction in (APPLY, RELEASE):
                    n0, s0 = ctx.read.value(variable, 0.5), ctx.read.secondary_rpm(0.5)
                    await _pulse(ctx, direction, pulse_s)
                    await ctx.sleep(1.5)
                    n1, s1 = ctx.read.value(variable, 0.5), ctx.read.secondary_rpm(0.5)
                    gains.append(abs(n1 - n0) / n0 / pulse_s)
                    if variable == "engine" and n1 != n0 and s0 > 0:
                        shares.append(abs(s1 - s0) / s0 / (abs(n1 - n0) / n0))
            g = statistics.fmean(gains)
            spread = (max(gains) - min(gains)) / g if g > 0 else math.inf
            kp = LOOP_GAIN_PER_S[variable] / g if g > 0 else math.inf
            shifting = statistics.median(shares) if shares else None
            ok = spread <= MAX_SPREAD and KP_RANGE[0] <= kp <= KP_RANGE[1] and not (
                shifting is not None and shifting > MAX_SHIFT_SHARE)
            result = {"ok": ok, "gain_rel_per_s": g, "pulse_gains_rel_per_s": gains, "spread": spread,
                      "kp_identified": kp, "kp_held": hold_kp}
            if shifting is not None:
                result["secondary_over_engine"] = shifting
            if not ok:
                result["reason"] = (
                    f"the CVT shifts here: each pulse moved the secondary {shifting:.1f}x as much as the engine "
                    "(relative), so the engine speed is the CVT's, not the brake's; hold the engine where the "
                    "CVT sits at a stop" if shifting is not None and shifting > MAX_SHIFT_SHARE
                    else f"pulses disagree (spread {spread:.0%})" if spread > MAX_SPREAD
                    else f"kp {kp:.2f} outside {KP_RANGE[0]}..{KP_RANGE[1]}")
    finally:
        ctx.brake(STOP)
    result.update(variable=variable, setpoint_rpm=setpoint, kp_key=KP_KEY[variable], kp_before=base.kp,
                  applied=False)
    return result
