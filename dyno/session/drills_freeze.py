"""The freeze drills, ``pi-freeze`` (issue 37) and ``loop-freeze`` (issue 49), and their verdict, read from the
simulated world's truth.

``pi-freeze``: the Pi stops for S seconds with every pin at its level: only what does not run on the Pi can make
the rig safe meanwhile — the Nano's run-enable (its heartbeat timeout) opening the kill chain, and K3 on that
chain driving the brake's release by wiring.  ``loop-freeze``: only the control loop stops (inside one of the
output driver's commands when the driver has a lock: ``--mock-pins``), while the poller's I/O thread and the
watchdog thread run on; the I/O thread withholds the heartbeat once the loop's stamp is stale
(:mod:`dyno.acquisition.poller`), so the Nano cuts, and the watchdog thread cuts too, without the driver's lock.

The record states who opened the chain, how long after the freeze (``latency_s``, true time), whether that is
within the heartbeat timeout + 0.1 s, and when the pads left the rotor against the release bound from the
actuator's true position at the cut.
"""

from __future__ import annotations

from dyno.session.safe_outputs import RELEASE_BOUND_MARGIN_S

#: the Nano's check comes within one loop pass of the timeout and the kill relay drops within ~20 ms; the
#: physics acts from its next 4 ms cell: 0.1 s is the issue's allowance beyond the timeout
CUT_ALLOWANCE_S = 0.1
LOOP_FREEZE_DEFAULT_S = 3.0
WORLD_STEP_S = 0.005  # the physics and the Nano stepped this often while the host is frozen


def pi_freeze(runner, d, rec: dict, default_s: float) -> None:
    """The whole host stops: no callback, no ticker (thread) runs; the world runs on."""
    from dyno.clock import freeze_host

    rec["freeze_s"] = float(d.arg) if d.arg else default_s
    freeze_host(runner.loop, rec["freeze_s"] / runner.speed, _world(runner.ctx.sim))
    rec["resumed_s"] = runner.sim_now()


def loop_freeze(runner, d, rec: dict) -> None:
    """The control loop blocks S s; the tickers standing for the I/O thread and the watchdog thread run on (and
    the world).  With the real-rig output code (``--mock-pins``) the loop is frozen inside one of its commands,
    holding the driver's lock, as a deadlocked driver call would."""
    from dyno.clock import block_loop

    ctx, loop = runner.ctx, runner.loop
    rec["freeze_s"] = float(d.arg) if d.arg else LOOP_FREEZE_DEFAULT_S
    poller = ctx.poller
    polls0, held0 = poller.polls, poller.held_ticks
    held = getattr(getattr(ctx.controller, "act", None), "_held", None)  # GpioActuators' lock
    rec["inside_driver_call"] = held is not None
    world = loop.add_ticker(_world(ctx.sim), WORLD_STEP_S)
    try:
        if held is not None:
            with held():
                block_loop(loop, rec["freeze_s"] / runner.speed)
        else:
            block_loop(loop, rec["freeze_s"] / runner.speed)
    finally:
        loop.remove_ticker(world)
    rec["resumed_s"] = runner.sim_now()
    # the watchdog thread's own cut (its kill relay) while the loop was still frozen, from the wiring's record
    rec["pi_kill_at_s"] = next((t for t, what, v in ctx.sim.actuators.history
                                if rec["onset_s"] <= t < rec["resumed_s"]
                                and (what == "safe_state" or (what == "kill" and v))), None)
    # the I/O thread's stand-in ran throughout: it polled until the loop's stamp was stale, then looked and held
    rec["io_polls_during_freeze"] = poller.polls - polls0
    rec["io_ticks_held"] = poller.held_ticks - held0
    rec["loop_tolerance_s"] = poller.loop_tolerance_s


def liveness_limit_s(ctx) -> float | None:
    """The longest loop stall that cuts nothing (docs/safety.md): the Nano's heartbeat timeout plus the I/O
    thread's tolerance, less two poll periods (the last stamp and the last poll before it); without an armed
    run-enable, the watchdog's timeout.  None when neither is known."""
    timeout_s = ctx.rig_cfg.limits.supervisor_timeout_s if getattr(ctx, "rig_cfg", None) else 0.0
    wd_s = getattr(getattr(ctx, "watchdog", None), "timeout_s", None)
    poller = getattr(ctx, "poller", None)
    if timeout_s > 0 and poller is not None:
        nano_s = timeout_s + poller.loop_tolerance_s - 2 * poller.poll_period_s
        return nano_s if wd_s is None else min(nano_s, wd_s)
    return wd_s


def stall_verdict(ctx, stall_s: float) -> tuple[bool, str]:
    """A ``loop-stall``'s hazard: the loop silent past its liveness limit (the engine is then cut)."""
    limit_s = liveness_limit_s(ctx)
    arose = limit_s is None or stall_s > limit_s
    note = (f"a {stall_s * 1e3:g} ms stall is within the loop's liveness limit ({limit_s or 0:.3f} s: the Nano's "
            "heartbeat timeout + the I/O thread's tolerance, or the watchdog): the loop was not silent past it")
    return arose, note


def _world(sim):
    truth = getattr(sim, "truth", None)

    def world() -> None:  # the physics and the Nano run on; the truth is sampled as if polled
        sim.bus.sync()
        if truth is not None:
            truth([], sim.model.t_s)
    return world


def freeze_verdict(ctx, rec: dict) -> None:
    """Add ``engine_cut_by``, ``engine_cut_at_s``, ``latency_s``, ``latency_bound_s``, ``pads_off_at_s``,
    ``pads_off_s`` (cut -> pads off), ``pads_off_bound_s`` and ``hazard_arose`` to a fired pi-freeze (in place)."""
    model = ctx.sim.model
    onset = rec["onset_s"]
    timeout_s = ctx.rig_cfg.limits.supervisor_timeout_s if getattr(ctx, "rig_cfg", None) else 0.0
    rec["supervisor_timeout_s"] = timeout_s
    cut = model.engine_cut(onset - 1e-9)
    was_on = _chain_closed_at(model, onset)
    # (loop-freeze: the I/O thread polls on for the loop's tolerance, then the Nano waits its timeout)
    allowed_s = timeout_s + rec.get("loop_tolerance_s", 0.0)
    long_enough = timeout_s <= 0 or rec.get("freeze_s", 0.0) > allowed_s
    rec["hazard_arose"] = bool(was_on and long_enough)
    if not was_on:
        rec["hazard_note"] = "the kill chain was already open when the Pi froze: nothing left to cut"
        return
    if not long_enough:
        rec["hazard_note"] = (f"a {rec.get('freeze_s'):g} s freeze is within the Nano's {timeout_s:g} s heartbeat"
                              f"{' (+ the loop tolerance)' if 'loop_tolerance_s' in rec else ''}: the host was back "
                              "in time, nothing had to be cut")
        return
    if cut is None:
        rec["engine_cut_by"] = None
        rec["latency_s"] = None
        rec["unsafe_because"] = "the kill chain stayed closed through the freeze and after"
        return
    t_cut, by = cut
    rec["engine_cut_by"] = by
    rec["engine_cut_at_s"] = t_cut
    rec["latency_s"] = t_cut - onset
    rec["latency_basis"] = "true time from the freeze to the kill chain opening (the physics)"
    if timeout_s > 0:
        rec["latency_bound_s"] = round(timeout_s + CUT_ALLOWANCE_S, 6)
        rec["latency_within_bound"] = rec["latency_s"] <= rec["latency_bound_s"]
    mm = getattr(model, "ignition_cut_mm", {}).get(t_cut)
    b = model.brake
    if mm is not None:
        rec["brake_position_at_cut_mm"] = round(mm, 3)
        rec["pads_off_bound_s"] = max(0.0, mm - b.a0_mm) / b.v_act_mm_s + RELEASE_BOUND_MARGIN_S
    off_at = model.pads_off_at_s if model.pads_off else None
    rec["pads_off_at_s"] = off_at
    rec["pads_off_s"] = None if off_at is None else max(0.0, off_at - t_cut)
    rec["k3_fitted"] = bool(model.brake_hold_relay)
    if "pads_off_bound_s" in rec:
        rec["pads_off_within_bound"] = rec["pads_off_s"] is not None and rec["pads_off_s"] <= rec["pads_off_bound_s"]
        if not rec["pads_off_within_bound"] and not model.brake_hold_relay:
            rec["pads_off_note"] = ("no K3 (rig.toml actuator.brake_hold_relay = false): the brake is released only "
                                    "when the Pi resumes")


def _chain_closed_at(model, t_s: float) -> bool:
    closed = False
    for t, on, _ in getattr(model, "ignition_log", []):
        if t > t_s:
            break
        closed = on
    return closed


def freeze_abort_latency(ctx, abort: dict, rec: dict) -> None:
    """A freeze's abort: the rig was made safe by the kill chain (the Nano, K3, the watchdog thread's cut), not by
    the loop's command after it resumed; both instants are stated (in place)."""
    if rec.get("engine_cut_at_s") is None:
        return
    abort["pi_latency_s"] = abort.get("latency_s")  # (the Pi's own safe state, when it resumed)
    abort["engine_cut_by"] = rec["engine_cut_by"]
    abort["engine_cut_at_s"] = rec["engine_cut_at_s"]
    abort["latency_s"] = rec["latency_s"]
    abort["latency_basis"] = ("true time from the freeze to the kill chain opening (the Nano's run-enable); the "
                              "Pi's own safe state followed when it resumed (safe_commanded_s, pi_latency_s)")
