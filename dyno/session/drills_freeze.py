"""The ``pi-freeze`` drill's verdict, read from the simulated world's truth (issue 37).

The Pi stops for S seconds with every pin at its level: only what does not run on the Pi can make the rig
safe meanwhile — the Nano's run-enable (its heartbeat timeout) opening the kill chain, and K3 on that chain
driving the brake's release by wiring.  The record states who opened the chain, how long after the freeze
(``latency_s``, true time), whether that is within the heartbeat timeout + 0.1 s, and when the pads left the
rotor against the release bound from the actuator's true position at the cut.
"""

from __future__ import annotations

from dyno.session.safe_outputs import RELEASE_BOUND_MARGIN_S

#: the Nano's check comes within one loop pass of the timeout and the kill relay drops within ~20 ms; the
#: physics acts from its next 4 ms cell: 0.1 s is the issue's allowance beyond the timeout
CUT_ALLOWANCE_S = 0.1


def freeze_verdict(ctx, rec: dict) -> None:
    """Add ``engine_cut_by``, ``engine_cut_at_s``, ``latency_s``, ``latency_bound_s``, ``pads_off_at_s``,
    ``pads_off_s`` (cut -> pads off), ``pads_off_bound_s`` and ``hazard_arose`` to a fired pi-freeze (in place)."""
    model = ctx.sim.model
    onset = rec["onset_s"]
    timeout_s = ctx.rig_cfg.limits.supervisor_timeout_s if getattr(ctx, "rig_cfg", None) else 0.0
    rec["supervisor_timeout_s"] = timeout_s
    cut = model.engine_cut(onset - 1e-9)
    was_on = _chain_closed_at(model, onset)
    long_enough = timeout_s <= 0 or rec.get("freeze_s", 0.0) > timeout_s
    rec["hazard_arose"] = bool(was_on and long_enough)
    if not was_on:
        rec["hazard_note"] = "the kill chain was already open when the Pi froze: nothing left to cut"
        return
    if not long_enough:
        rec["hazard_note"] = (f"a {rec.get('freeze_s'):g} s freeze is within the Nano's {timeout_s:g} s heartbeat: "
                              "the host was back in time, nothing had to be cut")
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
    """A pi-freeze's abort: the rig was made safe by the kill chain (the Nano, K3), not by the Pi's command
    after it resumed; both instants are stated (in place)."""
    if rec.get("engine_cut_at_s") is None:
        return
    abort["pi_latency_s"] = abort.get("latency_s")  # (the Pi's own safe state, when it resumed)
    abort["engine_cut_by"] = rec["engine_cut_by"]
    abort["engine_cut_at_s"] = rec["engine_cut_at_s"]
    abort["latency_s"] = rec["latency_s"]
    abort["latency_basis"] = ("true time from the freeze to the kill chain opening (the Nano's run-enable); the "
                              "Pi's own safe state followed when it resumed (safe_commanded_s, pi_latency_s)")
