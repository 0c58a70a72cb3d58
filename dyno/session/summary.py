"""What ``dyno run --json`` reports of a finished run (and the run directory's ``safety`` document).

Pure bookkeeping over the composition root's :class:`~dyno.session.root.RunContext`: the points, the link's
figures, the aborts with their true-time latencies and the outputs as the world has them
(:mod:`dyno.session.safe_outputs`).
"""

from __future__ import annotations

import math

from dyno.session.safe_outputs import add_release_to_abort, rig_outputs


def summarize(ctx, drills_from: int = 0) -> dict:
    """The run's JSON document; ``drills_from``: the first of ``ctx.drills.fired`` that belongs to this run
    (a UI session's re-armed runs share one drill runner)."""
    reader = ctx.poller.reader
    st = reader.stats
    frames = {"read": st.read, "accepted": st.accepted, "rejected": dict(sorted(st.rejected.items())),
              "rejected_total": sum(st.rejected.values()),
              "transport_errors": dict(sorted(st.transport_errors.items())),
              "device_resets": st.device_resets, "resyncs": st.resyncs,
              "boots": list(getattr(st, "boots", []))}  # v2: each boot seen, with its reset cause
    aborts = [dict(a) for a in ctx.controller.aborts]
    out = {"run_dir": str(ctx.writer.run_dir), "state": ctx.controller.state.value,
           "reason": ctx.controller.reason, "points": [public_point(p) for p in ctx.controller.points],
           "discarded": list(ctx.controller.discards), "skipped": list(getattr(ctx.controller, "skips", [])),
           "frames": frames, "events_lost": reader.events_lost, "aborts": aborts}
    zc = getattr(ctx.controller, "zero_check", None)
    if zc is not None:
        out["torque_zero"] = zc
        channel = getattr(ctx.controller, "input_channel", None)
        if channel is not None:  # the zero checks cover the engine-side input torque channel too
            zi = getattr(ctx.controller, "zero_check_input", None)  # as logged (torque_zero_input document)
            if zi is None:
                from dyno.analysis.input_torque import input_zero_check

                zi = input_zero_check(ctx.poller.streams, zc, channel)
            out["torque_zero_input"] = zi
        if zc.get("correct"):
            from dyno.analysis.systematic import run_basis
            from dyno.analysis.zero_check import corrected_point_keys

            basis = run_basis(getattr(ctx, "ambient", None), getattr(ctx, "rig_cfg", None))
            for pub, p in zip(out["points"], ctx.controller.points):
                pub.update(corrected_point_keys(p, zc, basis))
    out["link"] = link_document(ctx)
    out["supervisor"] = supervisor_document(reader)
    out["kill_probe"] = dict(getattr(ctx.controller, "kill_probe", None) or {})  # each kill path's dip before GO
    out["ambient"] = dict(getattr(ctx, "ambient", None) or {})  # the run's air (dyno.session.ambient)
    if getattr(ctx, "u95_terms", None):
        out["u95_terms"] = ctx.u95_terms  # what each term of efficiency_u95 assumes (dyno.analysis.u95_terms)
    if getattr(ctx.controller, "tare", None):
        out["torque_tare"] = ctx.controller.tare  # the zero the points were measured from
    out.update(ctx.controller.results)  # a characterisation's figures (engagement_rpm, ...), top level
    go_s = ctx.controller.go_s
    ends = [p["host_t_end_s"] for p in ctx.controller.points if p.get("host_t_end_s") is not None]
    # from GO to the end of the last measurement in rig seconds (host seconds over the paced session's scale)
    scale = getattr(ctx.controller, "time_scale", 1.0)
    out["test_time_s"] = (max(ends) - go_s) / scale if go_s is not None and ends else ctx.controller.results.get("test_time_s")
    out["warmup"] = ctx.controller.warmup  # the warm-up criterion as met before the first point (or None)
    outputs = rig_outputs(ctx)
    out["outputs"] = outputs
    out["rig_safe"] = bool(outputs.get("safe"))  # the physical state (dyno.session.safe_outputs), not a wish
    if any(a.get("path") == "kill_lead" for a in aborts):  # nothing here can stop the engine (kill_probe)
        out["rig_safe"] = False
        outputs["unsafe_because"] = ("the engine cannot be cut: neither the Pi's kill relay nor the Nano's "
                                     "run-enable stops it (the kill lead is open); stop it at its own switch or fuel")
    # wiring faults the Pi's output code found (an end switch contradicting the travel): [] when none
    out["rig_faults"] = list(outputs.get("driver_faults") or outputs.get("faults") or [])
    if not out["rig_safe"]:
        out["rig_unsafe_because"] = outputs.get("unsafe_because", "not in the safe state")
    refused = list(getattr(ctx.controller, "refused", []))
    act_refused = getattr(getattr(ctx.sim, "actuators", None), "refused", None) if ctx.sim is not None else None
    for t, what, value in (act_refused or getattr(ctx.controller.act, "refused", None) or []):
        refused.append({"command": what, "value": value, "t_s": t, "by": "actuators"})
    if refused:
        out["refused"] = refused  # commands refused after the safe state (a plan's cleanup, a late jog)
    if ctx.writer.error is not None:
        out["log_error"] = f"{ctx.writer.error.strerror or ctx.writer.error}"
    if ctx.signal_received is not None:
        out["signal"] = int(ctx.signal_received)
    if ctx.sim is not None:
        frames["corrupted_accepted"] = ctx.audit["corrupted_accepted"]
        out["faults_injected"] = dict(ctx.sim.bus.injected)
        out["sim_time_s"] = ctx.sim.model.t_s
        out["sim_world"] = ctx.sim.model.world.to_dict()  # the simulated truth: its engine, sensor, day
        fw_report = getattr(ctx.sim.firmware, "report", None)
        if fw_report is not None:  # --firmware-elf: which ELF was the Nano, and what its pins were given
            out["firmware"] = fw_report()
        from dyno.session.drills import hazard_verdicts, true_latencies

        if ctx.drills is not None:
            hazard_verdicts(ctx, drills_from)
            out["drills"] = ctx.drills.fired[drills_from:]

        true_latencies(ctx, aborts, drills_from)
    if aborts:
        add_release_to_abort(aborts[0], outputs)
    from dyno.runlog.files import finite  # JSON-safe: NaN and infinities become null

    return finite(out)


def link_document(ctx) -> dict:
    """The firmware link as the run used it: its transport and clock, the poll rate, the busiest second's share
    planned (every transfer the rig file's busiest second holds, ``planned_by_kind``: dyno.transports.wire_load)
    and measured (every transfer timed on the rig, charged at the link's clock on the simulator; above
    60 % measured: ``warnings`` names ``link_busy``) and the frames lost — polls that
    got no accepted frame (failed transfers, rejected frames: each re-polled, but late); ``poll_rates``: per
    rate the poller ran at (the waiting states' and the test's), the rate it held and its interval jitter."""
    from dyno.transports.budget import MAX_BUSY, clock_hz, planned_by_kind

    rig = getattr(ctx, "rig_cfg", None)
    st = ctx.poller.reader.stats
    meter = getattr(ctx, "link_meter", None)
    by_kind = planned_by_kind(rig, ctx.poller.full_poll_hz) if rig else None
    planned = round(sum(by_kind.values()), 4) if rig else None
    measured = round(meter.worst_frac(), 4) if meter is not None else None
    out = {"transport": getattr(rig, "transport", None), "clock_hz": clock_hz(rig) if rig else None,
           "poll_hz": ctx.poller.full_poll_hz, "derated_from_hz": getattr(rig, "derated_from_hz", None),
           "planned_busy_frac": planned, "measured_busy_frac": measured,  # the busiest second's share
           "planned_by_kind": by_kind,  # poll, more (MORE bursts), retry, boot, supervisor, thermometer
           "bus_busy_frac": measured if measured is not None else planned,
           "busy_basis": "measured" if meter is not None else "planned",
           "warnings": ["link_busy"] if measured is not None and measured > MAX_BUSY else [],
           "frames_lost": sum(st.transport_errors.values()) + sum(st.rejected.values()),
           "events_lost": ctx.poller.reader.events_lost}
    import asyncio

    try:
        pace = getattr(asyncio.get_running_loop(), "pace_stats", lambda: None)()
    except RuntimeError:  # (not on a loop)
        pace = None
    if pace is not None:  # a paced simulation (--speed N): the wall clock's view of its virtual one
        out["pace"] = pace
    timing = getattr(ctx.poller, "timing", None)
    if timing is not None and getattr(timing, "rates", None):
        # per rate polled at, over the whole run: the rate held, jitter p99 (|interval - median|), lateness p99
        out["poll_rates"] = timing.by_rate()
    return out


POINT_KEYS = ("index", "host_t_start_s", "host_t_end_s", "throttle_frac", "rpm_primary", "rpm_secondary", "ratio",
              "torque_secondary_nm", "power_out_w", "power_in_w",
              # efficiency_reason: why efficiency is null (no engine-map curve at the point's throttle, ...)
              "efficiency", "efficiency_sem", "efficiency_ci95", "efficiency_reason", "rpm_primary_std", "rpm_secondary_std", "torque_secondary_std_nm",
              "torque_secondary_sem_nm", "torque_secondary_sem_dof",
              "n_primary_edges", "n_secondary_edges", "n_adc", "duration_s", "settled_by", "valid",
              "efficiency_true", "rpm_primary_true", "rpm_secondary_true", "torque_secondary_true_nm", "driveline_loss_true_nm",
              "faults",
              # closed-loop plans (dyno.control): the setpoint held, and a ramp's I·alpha correction
              "setpoint_rpm", "setpoint", "hold_variable", "alpha_primary_rad_s2", "alpha_secondary_rad_s2",
              "inertia_torque_engine_nm", "inertia_torque_secondary_nm", "efficiency_uncorrected",
              "efficiency_uncorrected_interval95",
              # the systematic part beside the statistical CI (95 % half-widths; dyno.analysis.systematic)
              "efficiency_sys95", "efficiency_sys95_calibration", "efficiency_sys95_engine_map",
              "efficiency_sys95_friction",
              "efficiency_sys95_air", "efficiency_sys95_driveline", "efficiency_u95", "efficiency_u95_terms",
              "efficiency_interval95", "torque_zero_tare_nm",
              # which power the efficiency divides by ("input_torque" | "engine_map"); the input channel's
              # torque, its own terms, and the map's figure beside it (dyno.analysis.input_torque)
              "efficiency_source", "torque_input_nm", "torque_input_std_nm", "torque_input_u95_nm", "n_input",
              "efficiency_sys95_calibration_input", "efficiency_sys95_cradle", "efficiency_engine_map",
              "efficiency_engine_map_u95", "efficiency_engine_map_interval95", "power_in_engine_map_w",
              "torque_input_true_nm")


def public_point(p: dict) -> dict:
    out = {}
    for k in POINT_KEYS:
        if k in p:
            v = p[k]
            out[k] = None if isinstance(v, float) and math.isnan(v) else v
    return out




SAFETY_KEYS = ("state", "reason", "aborts", "drills", "outputs", "rig_safe", "rig_unsafe_because", "rig_faults",
               "refused", "kill_probe",
               "signal", "faults_injected", "sim_time_s", "events_lost")


def safety_document(summary: dict) -> dict:
    """The ``safety`` document every run directory ends with: what ``dyno run --json`` reports of its
    safety (drill records, true-time latencies from the onset, the physical outputs at the end)."""
    return {k: summary[k] for k in SAFETY_KEYS if k in summary}


def supervisor_document(reader) -> dict:
    """The Nano's run-enable as the host saw it (issue 37): present (capability bit), armed in the current
    boot, its last RUN flag, and every drop with its cause (device time in us, unwrapped)."""
    if getattr(reader, "supervisor_command", None) is None and not getattr(reader, "supervisor_present", None):
        return {"armed_by_host": False}
    return {"armed_by_host": reader.supervisor_command is not None, "present": reader.supervisor_present,
            "armed": reader.supervisor_armed, "run_enable": reader.run_enable,
            "drops": [dict(d) for d in reader.run_enable_drops], "events": len(reader.supervisor_events)}

