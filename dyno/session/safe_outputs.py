"""The rig's outputs at the end of a run, as the world has them — not as the program wished.

``rig_safe`` means throttle idle, ignition killed, brake released (pads off the rotor) and the actuator
de-energised:

* **simulated rig** (with or without ``--mock-pins``): read from the physics — its throttle, ignition,
  actuator power and the actuator's true position against the brake's free travel.  The release is
  timed in true (simulated) time: ``safe_commanded_s`` (the last moment the outputs became safe, whoever
  commanded it), ``released_at_s`` (the pads left the rotor), ``release_s`` between them, and its bound
  ``release_bound_s`` = (position then − free travel) ÷ actuator speed + 0.2 s.  The start-up likewise:
  ``startup_released_at_s`` (the pads first left the rotor; 0 if they never touched it) and
  ``ignition_enabled_at_s`` (the kill chain first closed; None if it never did).
* **real rig** (no position sensor): the driver's confirmation (:class:`dyno.hw.outputs.GpioActuators`):
  the end-of-travel input closed where ``rig.toml`` declares one, else the release stroke ran its full time
  uninterrupted (``release_basis``); a release interrupted or not confirmed makes the rig not safe, and
  ``unsafe_because`` says why.
"""

from __future__ import annotations

import asyncio

#: the release bound's allowance beyond the pure travel time: relay settle/transfer, one control period
RELEASE_BOUND_MARGIN_S = 0.2


def last_safe_transition(history: list, history_mm: list, ignore_kill=()) -> tuple[float | None, float | None]:
    """(sim time, actuator mm) of the last moment the wired inputs went from not safe to safe.

    Safe inputs: throttle idle, ignition killed, actuator not applying.  ``history`` is
    :class:`dyno.sim.rig.SimWiring`'s ``(t, what, value)`` list (``safe_state`` sets all three at once).
    """
    from dyno.sim.rig import wired_states

    was_safe = False
    found: tuple[float | None, float | None] = (None, None)
    for i, t, safe in wired_states(history, ignore_kill):
        if safe and not was_safe:
            found = (t, history_mm[i] if i < len(history_mm) else None)
        was_safe = safe
    return found


def sim_outputs(ctx) -> dict:
    """The simulated rig's outputs from its physics, with the release's true timing (module doc)."""
    from dyno.sim.rig import physical_outputs

    sim = ctx.sim
    model = sim.model
    outs = physical_outputs(model)
    driver = getattr(ctx.controller.act, "output_states", None)
    if driver is not None and getattr(ctx.controller.act, "release_basis", "absent") != "absent":
        d = driver()  # --mock-pins: the real-rig output code's own view beside the physics'
        outs["brake_estimate"] = d.get("brake_estimate")
        outs["driver_released"] = d.get("released")
        outs["driver_release_basis"] = d.get("release_basis")
        outs["driver_faults"] = d.get("faults", [])
        judge_driver(outs)
    wiring = getattr(sim.actuators, "wiring", None)
    from dyno.session.drills_kill import probe_kill_windows

    t_cmd, mm_at = (last_safe_transition(wiring.history, wiring.history_mm, probe_kill_windows(ctx))
                    if wiring is not None else (None, None))
    outs["safe_commanded_s"] = t_cmd
    outs["brake_position_at_safe_mm"] = None if mm_at is None else round(mm_at, 3)
    released_at = model.pads_off_at_s if model.pads_off else None
    outs["released_at_s"] = released_at
    outs["release_s"] = (max(0.0, released_at - t_cmd) if released_at is not None and t_cmd is not None
                         else None)
    if mm_at is not None:
        b = model.brake
        outs["release_bound_s"] = max(0.0, mm_at - b.a0_mm) / b.v_act_mm_s + RELEASE_BOUND_MARGIN_S
        outs["release_within_bound"] = outs["release_s"] is not None and outs["release_s"] <= outs["release_bound_s"]
    outs["release_basis"] = "physics"
    # the start-up, in true time: when the pads first left the rotor (0: never on it) and the chain first closed
    outs["startup_released_at_s"] = model.startup_released_at_s
    outs["ignition_enabled_at_s"] = model.ignition_enabled_at_s
    outs["brake_hold_relay"] = bool(model.brake_hold_relay)
    outs.update(engine_cut(model))
    if not outs["safe"]:
        outs["unsafe_because"] = _why_not(outs)
    return outs


def engine_cut(model) -> dict:
    """Who opened the kill chain for good (the opening that began its last open period: "pi", "nano" or
    "estop") and when, in true time; None while the chain is closed (:mod:`dyno.sim.kill_chain`)."""
    log = getattr(model, "ignition_log", [])
    last_on = max((i for i, (_, on, _) in enumerate(log) if on), default=-1)
    cut = next(((t, by) for t, on, by in log[last_on + 1:] if not on), None)
    return {"engine_cut_by": cut[1] if cut else None, "engine_cut_at_s": cut[0] if cut else None,
            "nano_run_enable": bool(getattr(model, "nano_enable", True))}


def judge_driver(outs: dict) -> None:
    """``driver_agrees``: the driver's verdict (released, i.e. pads off and de-energised, as its estimate
    and its end switch say) equals the physics' (pads off the rotor and the actuator de-energised);
    ``driver_disagreement`` names the difference when not (in place)."""
    physics = bool(outs.get("pads_off_rotor")) and outs.get("brake_actuator") == "stopped"
    said = bool(outs.get("driver_released"))
    outs["driver_agrees"] = said == physics
    if said != physics:
        where = (f"pads {'off' if outs.get('pads_off_rotor') else 'on'} the rotor at "
                 f"{outs.get('brake_position_mm')} mm, actuator {outs.get('brake_actuator')}")
        outs["driver_disagreement"] = (
            f"the driver says {'released' if said else 'not released'} (basis "
            f"{outs.get('driver_release_basis')}, estimate {outs.get('brake_estimate')}); the physics: {where}")


def hw_outputs(act) -> dict:
    """The real rig's outputs, read back from its pins, with the release's confirmation (module doc)."""
    report = getattr(act, "output_states", None)
    if not callable(report):
        return {"safe": False, "unsafe_because": "the outputs cannot be read back"}
    outs = dict(report())
    if not outs.get("safe"):
        outs["unsafe_because"] = _why_not(outs)
    return outs


def rig_outputs(ctx) -> dict:
    """The outputs' final states, by name, and whether together they are the safe state."""
    if ctx.sim is not None:
        return sim_outputs(ctx)
    return hw_outputs(ctx.controller.act)


def _why_not(outs: dict) -> str:
    why = []
    if outs.get("throttle") != "idle":
        why.append(f"throttle {outs.get('throttle')}")
    if outs.get("engine_kill") != "killed":
        why.append("ignition on")
    elif outs.get("engine_firing"):
        why.append("the engine still fires though killed (a kill path welded shut, or the kill lead open)")
    if outs.get("pads_off_rotor") is False:
        why.append(f"brake pads on the rotor (actuator at {outs.get('brake_position_mm')} mm)")
    if outs.get("brake_actuator") != "stopped":
        why.append(f"actuator {outs.get('brake_actuator')}")
    if outs.get("released") is False:
        why.append(outs.get("release_interrupted") or "release not confirmed (stroke not completed)")
    return "; ".join(why) or "not in the safe state"


def release_done(ctx) -> bool:
    """The release stroke has ended: the brake released and the actuator de-energised."""
    act = ctx.controller.act
    if ctx.sim is not None:
        m = ctx.sim.model
        if m.actuator_dir != 0 or not m.pads_off or ctx.sim.actuators.releasing:
            return False
    return bool(getattr(act, "released", True))


def pads_off(ctx) -> bool:
    """The brake's pads are off the rotor (the simulated world's; the rig has no such sensor: True)."""
    return ctx.sim is None or bool(ctx.sim.model.pads_off)


async def finish_release(ctx, *, poll_s: float = 0.1, pads_only: bool = False) -> bool:
    """Keep servicing the outputs until the release stroke has ended (sim and rig); True if it did.

    ``pads_only``: until the pads are off the rotor (within ``release_bound_s`` of the safe state), not
    the whole stroke to the retracted end (seconds): a session whose terminal went ends at once, the
    stroke then completed by the wiring (hardware/README.md: K3, released pins); docs/safety.md.
    """
    act = ctx.controller.act
    stroke_s = float(getattr(act, "brake_full_stroke_s", 8.0))
    loop = asyncio.get_running_loop()
    end = loop.time() + 2.0 * stroke_s + 1.0  # the drivers add their own margins to a full stroke
    while loop.time() < end:
        if release_done(ctx) or (pads_only and pads_off(ctx)):
            return True
        await asyncio.sleep(poll_s)
        act.tick(loop.time())
        if ctx.watchdog is not None:
            ctx.watchdog.kick()  # the loop is alive and servicing the release
    return release_done(ctx)


def add_release_to_abort(abort: dict, outs: dict) -> None:
    """The drill's record states the release beside its latency (in place)."""
    for k in ("brake_position_at_safe_mm", "released_at_s", "release_s", "release_bound_s", "release_within_bound"):
        if k in outs:
            abort[k] = outs[k]
