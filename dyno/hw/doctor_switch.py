"""``dyno doctor``'s checks of the rig's safety inputs and of the end-of-travel switch.

* **Declared** (read-only, every rig: each has an engine and its kill chain): the E-stop chain's monitor input
  (``pins.estop_input``) and the end switch (``pins.brake_released_input``), as hardware/README.md wires them.
  One the rig file leaves out is a FAIL naming it: the monitors are part of the shipped wiring, not options.
* **The end switch with ``--toggle``**: closed at the retracted stop, open one brake step out, closed again
  back at the stop, over :data:`SWITCH_READS` reads each.  Without K3 the step runs with the ignition killed.
  With K3 (the shipped rig) the driver's path runs through K3's NO contacts, so the apply step needs the kill
  chain closed: the switch is first read at the stop after the start-up's full-stroke release (stuck open
  found without moving anything); then, only while the engine is stopped (no Hall edges), the chain is closed
  for that one step (the Pi's relay, and the Nano's run-enable armed and polled through it), the watchdog
  running, and opened again at once — K3 and the driver release.  A pass clears a standing end-switch fault
  (:mod:`dyno.hw.rig_faults`), so K3 is never bypassed by hand.
"""

from __future__ import annotations

from dyno.errors import SafetyAbort
from dyno.hw.doctor_report import FAIL, OK, SKIP

#: end-switch reads per position (0.1 s of them): a loose contact that closes on a few % of reads shows
SWITCH_READS = 200


def switch_sample(act) -> str | None:
    """"closed", "open" or "chatters" over :data:`SWITCH_READS` reads (None: no switch declared)."""
    if act.end_switch_closed() is None:
        return None
    reads = set()
    for _ in range(SWITCH_READS):
        reads.add(act.end_switch_closed())
        act.clock.sleep(0.1 / SWITCH_READS)
        act.tick(act.clock.now())  # (doctor is the loop here: its tick is the watchdog's sign of life)
    return "chatters" if len(reads) > 1 else ("closed" if True in reads else "open")


def check_end_switch(report: Report, cfg, act, at_stop: str, out: str, back: str, persisted: bool) -> None:
    """The end-of-travel switch against a measured stroke: closed at the retracted stop, open one brake step
    out, closed again back at the stop — each over :data:`SWITCH_READS` reads — and no fault found by the
    driver on the way.  A pass clears a standing end-switch fault (:mod:`dyno.hw.rig_faults`): the rig may be
    armed again."""
    wire = f"GPIO{cfg.pins.brake_released_input} (pins.brake_released_input)"
    why = []
    if "chatters" in (at_stop, out, back):
        why.append("chatters (reads both ways at one position): a loose contact or a worn switch?")
    elif at_stop != "closed" or back != "closed":
        why.append("reads open at the retracted stop: stuck open, wire cut or connector off?")
    elif out != "open":
        why.append(f"reads closed {cfg.actuator.step_s:.2f} s out from the stop: stuck closed or shorted to ground?")
    found = [f for f in act.faults if f.get("channel") == "end_switch" and not f.get("inherited")]
    if found and not why:
        why.append(found[0]["detail"])
    if why:
        report.add("end switch", FAIL, f"{wire} {'; '.join(why)} (check the switch and its wire)")
        return
    cleared = False
    if persisted:
        from dyno.hw import rig_faults

        cleared = rig_faults.clear("end_switch")
    report.add("end switch", OK, f"{wire}: closed at the stop, open {cfg.actuator.step_s:.2f} s out, closed back"
               + ("; the standing end-switch fault is cleared" if cleared else ""))




#: how long the shafts must show no Hall edge before the chain is closed for the step (engine stopped)
QUIET_S = 1.0
#: the Nano's run-enable must confirm RUN within this long once armed (a few polls)
ARM_WAIT_S = 1.0


def check_safety_inputs(report, cfg) -> None:
    """FAIL for each safety input the rig file does not declare (module doc)."""
    wanted = (("e-stop input", "estop_input", "the E-stop chain's monitor contact S1.3 to GND (GPIO22, header pin 15)"),
              ("end switch", "brake_released_input",
               "the brake's end-of-travel switch S2 to GND (GPIO27, header pin 13)"))
    for name, key, what in wanted:
        if getattr(cfg.pins, key, None) is None:
            report.add(name, FAIL, f"pins.{key} not declared: a rig with an engine monitors {what}, as "
                       "hardware/README.md wires it; declare it in the rig file's [pins]")


def check_end_switch_k3(report, cfg, hw, transport, clock) -> None:
    """The end switch on a rig with K3 (module doc); ``hw``: the claimed :class:`dyno.hw.rig.HardwareRig`."""
    from dyno.control.outputs import APPLY

    act = hw.actuators
    at_stop = switch_sample(act)  # after the start-up's full-stroke release (check_outputs waited it out)
    if at_stop is None:
        report.add("brake step", SKIP, "K3 fitted and no end switch declared: nothing to check the step with",
                   essential=False)
        return
    wire = f"GPIO{cfg.pins.brake_released_input} (pins.brake_released_input)"
    if at_stop != "closed":
        why = ("chatters at the retracted stop (reads both ways): a loose contact or a worn switch?" if at_stop ==
               "chatters" else "reads open at the retracted stop after a full-stroke release: stuck open, wire cut "
               "or connector off?")
        report.add("end switch", FAIL, f"{wire} {why} (check the switch and its wire; nothing was moved)")
        return
    found = _found(act)
    if found:  # the driver judged the switch on the start-up release already: no step needed to name it
        report.add("end switch", FAIL, f"{wire} {found} (check the switch and its wire; nothing was moved)")
        return
    reader = _reader(cfg, transport)
    _poll_edges(reader, clock)  # (the first poll drains what the device buffered while nobody polled)
    edges = _serviced(act, reader, clock, QUIET_S, cfg.poll_hz)
    if edges:
        report.add("end switch", FAIL, f"{wire}: not stepped: {edges} Hall edges in {QUIET_S:.0f} s with the "
                   "ignition killed (the engine or a shaft still turns): stop the engine, then run this again")
        return
    if not _arm_run_enable(act, reader, cfg, clock):
        report.add("end switch", FAIL, f"{wire}: not stepped: the Nano's run-enable did not close the chain "
                   f"within {ARM_WAIT_S:.0f} s (firmware v2 with its supervisor, [limits] supervisor_timeout_s)")
        return
    try:
        act.engine_kill(False)  # the chain closed for this one step: K3 hands the actuator to the driver
        act.brake_step(APPLY, cfg.actuator.step_s)
        turned = _serviced(act, reader, clock, 2 * cfg.actuator.relay_settle_s + cfg.actuator.step_s + 0.05,
                           cfg.poll_hz)
        out = switch_sample(act)
    except SafetyAbort as e:  # the driver refused the step (it latched on a fault it found): name the switch
        report.add("end switch", FAIL, f"{wire}: the step was refused: {_found(act) or e} (check the switch and "
                   "its wire)")
        return
    finally:
        act.engine_kill(True)  # open again at once: K3 releases by wiring, the driver's release follows
    act.safe_state()
    act.finish_release()
    back = switch_sample(act)
    if turned:
        report.add("end switch", FAIL, f"{wire}: the step was cut short: {turned} Hall edges with the chain closed")
        return
    if hw.watchdog is not None and hw.watchdog.tripped:
        report.add("brake step", FAIL, "the watchdog tripped during the step")
        return
    report.add("brake step", OK, f"{cfg.actuator.step_s:.2f} s out with the kill chain closed for the step alone, "
               "engine stopped, watchdog running; back by K3 and the release", essential=False)
    check_end_switch(report, cfg, act, at_stop, out, back, hw.persist_faults)


def _found(act) -> str | None:
    """The end-switch fault the driver found this session (None: none)."""
    found = [f for f in act.faults if f.get("channel") == "end_switch" and not f.get("inherited")]
    return found[0]["detail"] if found else None


def _reader(cfg, transport):
    from dyno.acquisition.reader import make_reader
    from dyno.protocol import v2

    lim = cfg.limits
    command = None
    if cfg.protocol == "v2" and lim.supervisor_timeout_s > 0:
        command = v2.supervisor_command(lim.overspeed_primary_rpm, lim.overspeed_secondary_rpm,
                                        lim.supervisor_timeout_s)
    return make_reader(cfg.protocol, transport, supervisor_command=command)


def _poll_edges(reader, clock) -> int:
    from dyno.protocol import v1

    try:
        events = reader.poll(clock.now())
    except Exception:  # noqa: BLE001 - a failed poll is the reader's to count; the next one may pass
        return 0
    return sum(1 for ev in events if ev.channel in (v1.CH_PRIMARY, v1.CH_SECONDARY))


def _arm_run_enable(act, reader, cfg, clock) -> bool:
    """The Nano's run-enable on (armed by the reader's polls); True where the rig has none in its chain."""
    if getattr(reader, "supervisor_command", None) is None:
        return True
    t_end = clock.now() + ARM_WAIT_S
    while clock.now() < t_end:
        _poll_edges(reader, clock)
        if reader.supervisor_armed:
            return True
        clock.sleep(1.0 / cfg.poll_hz)
        act.tick(clock.now())
    return reader.supervisor_present is False  # (a firmware without the supervisor: the chain has no Q2)


def _serviced(act, reader, clock, seconds: float, poll_hz: float) -> int:
    """Run the step as the control loop would: the driver ticked and the Nano polled (its heartbeat) for
    ``seconds``; the Hall edges seen meanwhile."""
    n, t_end = 0, clock.now() + seconds
    while clock.now() < t_end:
        n += _poll_edges(reader, clock)
        act.tick(clock.now())
        clock.sleep(1.0 / poll_hz)
    act.tick(clock.now())
    return n
