"""``dyno doctor``'s check of the Nano's run-enable (issue 37).

``OK``, ``WARN``, ``SKIP``: the report's statuses (dyno.hw.doctor).
"""

from __future__ import annotations


def check_run_enable(report, OK, WARN, SKIP, cfg, transport) -> None:
    """The Nano's run-enable (issue 37): does the firmware have it (its capabilities frame), will dyno arm it."""
    from dyno.errors import FrameError
    from dyno.protocol import v2
    from dyno.transports.base import TransportFault

    timeout_s = cfg.limits.supervisor_timeout_s
    caps = None
    for _ in range(3):  # (a data frame answers while the boot still probes, or from a firmware without CAPS)
        try:
            frame = v2.decode_frame(transport.transfer(v2.encode_command(v2.OP_CAPS), v2.FRAME_MAX))
        except (TransportFault, FrameError, OSError):
            continue
        if isinstance(frame, v2.CapsFrame):
            caps = frame
            break
    if caps is not None and caps.has_supervisor:
        how = (f"dyno arms it at every boot (heartbeat {timeout_s:g} s, the [limits] over-speeds)" if timeout_s > 0
               else "not armed: [limits] supervisor_timeout_s = 0 (its transistor must then be out of the chain)")
        report.add("run-enable", OK, f"present (D7); {how}", essential=False)
    elif timeout_s > 0:
        report.add("run-enable", WARN, "absent (firmware before 2.1.0): with the Nano's transistor in the kill chain "
                   "the engine cannot run; flash the current firmware or set [limits] supervisor_timeout_s = 0",
                   essential=False)
    else:
        report.add("run-enable", SKIP, "absent, and not armed ([limits] supervisor_timeout_s = 0)", essential=False)
