"""The coast-down / parasitic-loss test (plan ``coast-down``).

Procedure: the torque gauge's zero is read at rest (engine at idle, below engagement,
brake released); full throttle with the brake released spins the driven side up to
full shift; then the engine is cut and the throttle closed -- that is the safe state,
so :meth:`Actuators.safe_state` starts the coast.  The belt keeps coupling the engine
(and back-shifts) until the primary falls below engagement; the analysis uses only the
revolutions after the primary is below ``uncoupled_primary_rpm``.  When the secondary
has stopped the zero is read again, and the loss fit (:mod:`dyno.analysis.coastdown`)
goes to the run (``characterisation`` document, ``dyno run --json``) and to
``driven_loss.json`` in the run directory: the file ``--driven-loss`` takes to add the
loss back to the efficiency of later runs.

Hall plausibility checks assume a running engine; the coast is the safe state with the
engine cut on purpose, so the controller stops expecting it (``engine_cut``); the other
checks (link, temperature, over-speed, ADC) go on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dyno.analysis import coastdown as cd
from dyno.control.api import PlanContext, State
from dyno.protocol import v1


@dataclass(frozen=True)
class CoastDownPlan:
    zero_s: float = 4.0  # torque zero read at rest, before and after
    spin_up_s: float = 6.0  # full throttle, brake released: full shift
    uncoupled_primary_rpm: float = 1500.0  # below any engagement: the belt no longer drives
    uncoupled_ratio_drop: float = 0.03  # ... or the speed ratio falls this far below its coupled maximum
    max_coast_s: float = 90.0
    min_secondary_rpm: float = 60.0  # below this the periods are too long to difference
    # The driven side's inertia (referred to the secondary) and the part beyond the gauge are the rig's:
    # rig.toml [inertia] (dyno.rig.config.InertiaConfig), the controller's ``inertia``.


async def run_coast_down(ctx: PlanContext, cp: CoastDownPlan) -> None:
    jc = ctx.config.inertia
    inertia, inertia_unc, beyond = jc.driven_kg_m2, jc.driven_rel_unc, jc.beyond_gauge_kg_m2
    ctx.phase(State.WARMUP, "idle, brake released: torque zero at rest")
    ctx.throttle(0.0)
    d0 = ctx.read.device_now_us()
    await ctx.sleep(cp.zero_s)
    zero_before = ctx.read.zero_nm(d0 + 500_000, ctx.read.device_now_us())
    ctx.phase(State.STEP, "full throttle, brake released: spin up to full shift")
    ctx.throttle(1.0)
    await ctx.sleep(cp.spin_up_s)
    rs_top = ctx.read.rpm(v1.CH_SECONDARY)
    ctx.phase(State.SETTLE, "engine cut, brake released: coasting down")
    ctx.cut_engine()  # a deliberate cut (brake released, ignition off): not a trip, nothing latched
    t_cut = ctx.read.device_now_us()
    t_unc = None
    t0 = ctx.now()
    ratio_max = 0.0
    while ctx.now() - t0 < cp.max_coast_s:
        await ctx.sleep(0.1)
        # Uncoupled: the engine falls away from the secondary (the ratio drops 3 % below the highest
        # it reached while coupled -- the back-shift only raises it), or is below any engagement.
        r = ctx.read.ratio()
        if t_unc is None and math.isfinite(r):
            ratio_max = max(ratio_max, r)
            if r < (1.0 - cp.uncoupled_ratio_drop) * ratio_max and ctx.now() - t0 > 1.0:
                t_unc = ctx.read.device_now_us() + 300_000  # past the live ratio's window
        if t_unc is None and ctx.read.rpm(v1.CH_PRIMARY) < cp.uncoupled_primary_rpm:
            t_unc = ctx.read.device_now_us()
        if ctx.read.rpm(v1.CH_SECONDARY) == 0.0:
            break
    t_stop = ctx.read.device_now_us()
    ctx.phase(State.MEASURE, "at rest: torque zero after")
    await ctx.sleep(cp.zero_s)
    zero_after = ctx.read.zero_nm(t_stop + 500_000, ctx.read.device_now_us())
    res: dict = {"secondary_rpm_at_cut": rs_top, "inertia_kg_m2": inertia,
                 "zero_before_nm": zero_before[0], "zero_after_nm": zero_after[0]}
    if t_unc is None:
        ctx.fail("error", f"coast-down: the primary never fell below {cp.uncoupled_primary_rpm:.0f} rpm")
        return
    s = ctx.read.edges(v1.CH_SECONDARY, t_unc, t_stop)
    dec = cd.decelerations(s, t_unc)
    keep = dec["omega_rad_s"] > cp.min_secondary_rpm * cd.RAD_PER_RPM
    try:
        fit = cd.fit_loss(dec["omega_rad_s"][keep], dec["alpha_rad_s2"][keep], inertia, inertia_unc)
    except ValueError as exc:
        ctx.fail("error", str(exc))
        return
    res["loss_fit"] = fit
    # the gauge's share (constant drag beyond it) and the loss it does not see
    t_end = int(dec["t_s"][keep][-1] * 1e6) if keep.any() else t_stop
    gauge = ctx.read.zero_nm(t_unc, t_end)
    z = zero_after if math.isfinite(zero_after[0]) else zero_before
    mean_alpha = float(np.mean(dec["alpha_rad_s2"][keep]))
    split = cd.split_seen(gauge[0], gauge[1], z[0], z[1], beyond, mean_alpha)
    res.update(split)
    res["unseen_torque_nm"] = (np.asarray(fit["torque_nm"]) - split["seen_nm"]).tolist()
    res["loss_rpm_range"] = [fit["rpm_min"], fit["rpm_max"]]
    ctx.set_results(res)
    _write_loss_file(ctx, res)
    ctx.phase(State.DONE, f"coast-down: loss fitted over {fit['rpm_min']:.0f}-{fit['rpm_max']:.0f} rpm")


def _write_loss_file(ctx: PlanContext, res: dict) -> None:
    """``driven_loss.json`` beside the run's log (what ``--driven-loss`` reads)."""
    doc = {"schema": "dyno.driven_loss/1", "loss_fit": res["loss_fit"], "seen_nm": res["seen_nm"],
           "seen_ci95_nm": res["seen_ci95_nm"]}
    ctx.write_artifact("driven_loss.json", doc)
