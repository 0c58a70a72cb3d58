"""The firmware-in-the-loop harness's run-enable supervisor (:mod:`dyno.session.firmware_sim`) (issue 37): the host's side of it and the report.

The host sends the rig file's ``[limits]`` (``overspeed_primary_rpm``, ``overspeed_secondary_rpm``,
``supervisor_timeout_s``) in one SET_SUPERVISOR at every boot, after the boot's first frame, as the host
will (:func:`dyno.protocol.v2.supervisor_command`); until then the output stays off. ``--host-stop-at S``
stops the host's polls at S simulated seconds while the simulation goes on (the host comes back after the
drain to read what the device kept, as a host recovering from a freeze would, so the cause event can be
decoded). ``--no-limits`` never sends the limits. ``--pulse-at S`` sends the kill-path probe's
PULSE_RUN_ENABLE (``--pulse-ms``, issue 49): D7 off that long, then on again (cause ``pulse``).

The report, ``supervisor: {on_at_s, off_at_s, cause, ...}``, is on the simulation's time base (seconds
since power-up): on and off come from the pin (D7 as the harness saw it: the physics' truth; for the
old-bootloader build the charge pump's output), the cause of each drop from the tag-5 events the host
decoded, a reset from the boot change the host saw:

* ``off_at_s`` is a number whenever the output is off at the end (when it went off; when it never went on,
  when the host first found it off: its first frame), null when it is on;
* ``cause``: ``heartbeat``, ``overspeed_primary`` / ``overspeed_secondary`` (the device's event), ``reset``
  (the pin dropped and the host then saw a new boot), ``no_limits`` (never armed), ``pump_stopped`` (the
  pump build's pulses stopped with neither an event nor a reset: a hung loop without a watchdog),
  ``unknown``; null while on.
"""

from __future__ import annotations

from dyno.protocol import v1, v2



class SupervisorHost:
    """What the host does about the run-enable, and what it decoded of it."""

    def __init__(self, spec) -> None:
        """``spec``: a :class:`dyno.session.firmware_sim.FirmwareSimSpec` (``protocol``, ``no_limits``, ``rig``,
        ``host_stop_at``, ``rearm_at``)."""
        self.command = None
        self.limits = None
        if spec.protocol == "v2" and not spec.no_limits:
            from dyno.rig.config import load_rig

            lim = load_rig(spec.rig).limits
            self.limits = {"overspeed_primary_rpm": lim.overspeed_primary_rpm,
                           "overspeed_secondary_rpm": lim.overspeed_secondary_rpm,
                           "timeout_s": lim.supervisor_timeout_s}
            if lim.supervisor_timeout_s > 0:  # 0 in the rig file: the run-enable is not armed
                self.command = v2.supervisor_command(lim.overspeed_primary_rpm, lim.overspeed_secondary_rpm,
                                                     lim.supervisor_timeout_s)
        self.stop_at = spec.host_stop_at
        self.rearm_at = getattr(spec, "rearm_at", None)
        self.rearmed_at_s = None  # when the operator's re-arm was asked for
        self.pulse_at, self.pulse_ms = getattr(spec, "pulse_at", None), getattr(spec, "pulse_ms", 100)
        self.pulsed_at_s = None  # when the kill-path probe's pulse was asked for
        self.sends: list = []          # (t_s, boot_id)
        self.events: list = []         # (t_s decoded, boot_id, Event)
        self.boot_seen: list = []      # (t_s, boot_id): the host's first frame of each boot
        self.last_poll_s = None        # the last poll before the host stopped
        self._boot = None

    def polling(self, t: float, t_end: float) -> bool:
        """Does the host poll at t? (not between --host-stop-at and the end of the drain)"""
        return self.stop_at is None or t < self.stop_at or t > t_end

    def maybe_rearm(self, reader, t: float) -> None:
        """``--rearm-at S``: the operator re-arms (the reader re-sends the limits until a frame shows RUN)."""
        if self.rearm_at is not None and self.rearmed_at_s is None and t >= self.rearm_at:
            self.rearmed_at_s = t
            reader.rearm_supervisor()

    def maybe_pulse(self, reader, t: float) -> None:
        """``--pulse-at S``: the kill-path probe (issue 49): PULSE_RUN_ENABLE of ``--pulse-ms``, written by the next
        poll (the reader's own path, as ``dyno run``'s probe)."""
        if self.pulse_at is not None and self.pulsed_at_s is None and t >= self.pulse_at:
            self.pulsed_at_s = t
            reader.pulse_run_enable(self.pulse_ms)

    def after_poll(self, reader, t: float, new: list) -> None:
        """After each poll: note the boot, the limits the reader sent (it arms every boot as ``dyno run``'s
        does: :func:`dyno.acquisition.reader.make_reader`'s ``supervisor_command``) and the tag-5 events it
        decoded (it takes them out of the stream, handing their GAP mark to the next event)."""
        if self.stop_at is None or t < self.stop_at:
            self.last_poll_s = t
        boot = reader.boot_id
        if boot is not None and boot != self._boot:
            self._boot = boot
            self.boot_seen.append((t, boot))
        sent = getattr(reader, "supervisor_sent", [])
        for b in sent[len(self.sends):]:
            self.sends.append((t, b))
        evs = getattr(reader, "supervisor_events", [])
        for d in evs[len(self.events):]:
            self.events.append((t, d["boot_id"], v1.Event(v2.CH_SUPERVISOR, d["t_us"], d["code"], d["status"])))


def _periods(transitions: list) -> list:
    """[(on_s, off_s | None)] from the harness's [[t_us, level], ...]."""
    out, on = [], None
    for t_us, level in transitions:
        if level and on is None:
            on = t_us / 1e6
        elif not level and on is not None:
            out.append((on, t_us / 1e6))
            on = None
    if on is not None:
        out.append((on, None))
    return out


def report(host: SupervisorHost, hs: dict, first_frame_s) -> dict:
    re_ = hs.get("run_enable") or {}
    periods = _periods(re_.get("transitions") or [])
    off_events: dict = {}
    for _, boot, ev in host.events:
        if ev.status != v2.SUP_ON:
            off_events.setdefault(boot, []).append(ev)
    per_boot: dict = {}
    history = []
    for on_s, off_s in periods:
        sent = [b for t, b in host.sends if t <= on_s]
        boot = sent[-1] if sent else None
        j = per_boot.get(boot, 0)
        per_boot[boot] = j + 1
        cause = None
        if off_s is not None:
            evs = off_events.get(boot, [])
            if len(evs) > j:
                cause = v2.SUP_CAUSE_NAMES.get(evs[j].status, f"status_{evs[j].status}")
            elif any(b != boot and t >= off_s for t, b in host.boot_seen):
                cause = "reset"
            elif re_.get("model") == "pump" and not re_.get("pulsing"):
                cause = "pump_stopped"
            else:
                cause = "unknown"
        history.append({"on_at_s": round(on_s, 6), "off_at_s": None if off_s is None else round(off_s, 6),
                        "cause": cause, "boot_id": boot})
    if history:
        last = history[-1]
        on_at, off_at, cause = last["on_at_s"], last["off_at_s"], last["cause"]
    else:  # never on: off since power-up, found off by the host's first frame
        on_at, off_at, cause = None, round(first_frame_s if first_frame_s is not None else 0.0, 6), "no_limits"
    return {
        "on_at_s": on_at, "off_at_s": off_at, "cause": cause,
        "on": bool(re_.get("on")),
        "model": re_.get("model"), "pulsing": re_.get("pulsing"),
        "max_pulse_interval_us": re_.get("max_pulse_interval_us") if re_.get("model") == "pump" else None,
        "last_pulse_s": re_["last_edge_us"] / 1e6 if re_.get("model") == "pump" else None,
        "pump_hold_s": re_["pump_hold_us"] / 1e6 if re_.get("model") == "pump" else None,
        "limits": host.limits, "limits_sent": host.command is not None,
        "limits_sent_at_s": [t for t, _ in host.sends],
        "host_stop_at_s": host.stop_at, "last_poll_s": host.last_poll_s,
        "rearm_at_s": host.rearm_at, "rearmed_at_s": host.rearmed_at_s,
        "pulse_at_s": host.pulse_at, "pulse_ms": host.pulse_ms if host.pulse_at is not None else None,
        "pulsed_at_s": host.pulsed_at_s,
        "history": history,
        "events": [{"decoded_at_s": round(t, 6), "boot_id": b, "t_us": ev.t_us,
                    "cause": v2.SUP_CAUSE_NAMES.get(ev.status, f"status_{ev.status}"), "code": ev.code}
                   for t, b, ev in host.events],
    }
