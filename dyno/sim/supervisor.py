"""The Nano's run-enable supervisor, emulated (firmware/src/supervisor.c; docs/protocol.md, issue 37).

The output (D7) is on only while the host's limits arrived in this boot (``SET_SUPERVISOR``), a valid poll
came within the heartbeat timeout, and no Hall period measured since arming was shorter than its
channel's minimum (an over-speed).  A drop latches until the next ``SET_SUPERVISOR``; a pulse
(``PULSE_RUN_ENABLE``, the kill-path probe of issue 49) turns it off for its length and on again, unless the
heartbeat expired or an over-speed came meanwhile (then it stays off with that cause); a reset drops it
and the new boot is not armed.  Each change is one tag-5 event: ``status`` the cause, ``code`` the
measured value (``dyno.protocol.v2.SUP_*``).  Decisions are taken in simulation seconds at the exact
instant the firmware's loop would find them (the heartbeat's expiry, the edge that ended a short
period); the firmware adds at most one loop pass (< 1 ms).
"""

from __future__ import annotations

from dyno.protocol import v1, v2


class NanoSupervisor:
    """State of one boot's supervisor; ``push(tag, t_s, code, status)`` queues its events."""

    def __init__(self, push, on_change=None, pace: float = 1.0) -> None:
        self._push = push
        self.on_change = on_change  # f(on: bool, t_s: float, cause: str): the wiring (the kill chain)
        # A simulation paced at N x real time (``dyno ui --speed N``) stretches every real-time delay of the host
        # N times in the rig's time: the heartbeat timeout spans the same real time it does at 1x (as the
        # emulated ring's size does: dyno.ui.session), or a 25 ms screen refresh at x8 would be a 0.2 s silence.
        self.pace = float(pace)
        self.boot(0.0, cause="power-on")

    def boot(self, t_s: float, cause: str = "reset") -> None:
        """A boot: not armed, output off until the host's limits arrive."""
        was_on = getattr(self, "on", False)
        self.armed = False
        self.on = False
        self.pulse_end_s: float | None = None  # off for a pulse until then (not latched)
        self.min_period_us = {v1.CH_PRIMARY: 0, v1.CH_SECONDARY: 0}
        self.timeout_s = 0.0
        self.last_beat_s = t_s
        self.armed_at_s = t_s
        if was_on:
            self._change(False, t_s, cause)

    def _change(self, on: bool, t_s: float, cause: str) -> None:
        self.on = on
        if self.on_change is not None:
            self.on_change(on, t_s, cause)

    def heartbeat(self, t_s: float) -> None:
        """A CRC-valid POLL / ACK_POLL / SET_SUPERVISOR."""
        self.service(t_s)  # (an expiry before this poll has happened already)
        self.last_beat_s = t_s

    def arm(self, t_s: float, min_period_primary_us: int, min_period_secondary_us: int, timeout_ms: int) -> bool:
        """SET_SUPERVISOR: limits stored, heartbeat restarted, only later periods count, output on.

        A timeout of 0 is not a command (ignored, as by the firmware): False."""
        if timeout_ms <= 0:
            return False
        self.min_period_us = {v1.CH_PRIMARY: int(min_period_primary_us), v1.CH_SECONDARY: int(min_period_secondary_us)}
        self.timeout_s = timeout_ms / 1000.0 * self.pace
        self.armed = True
        self.pulse_end_s = None
        self.armed_at_s = self.last_beat_s = t_s
        self._push(v2.CH_SUPERVISOR, t_s, 0, v2.SUP_ON)
        if not self.on:
            self._change(True, t_s, "on")
        return True

    def pulse(self, t_s: float, ms: int) -> bool:
        """PULSE_RUN_ENABLE at ``t_s``: an output that is on goes off for ``ms`` (True); otherwise nothing."""
        self.service(t_s)
        if ms == v2.PULSE_LATCH and (self.on or self.pulse_end_s is not None):  # off, latched until an arm
            was_on, self.pulse_end_s = self.on, None
            self._push(v2.CH_SUPERVISOR, t_s, int(ms), v2.SUP_PULSE)
            if was_on:
                self._change(False, t_s, "pulse")
            return True
        if not self.on:
            return False
        self.pulse_end_s = t_s + ms / 1000.0 * self.pace
        self._push(v2.CH_SUPERVISOR, t_s, int(ms), v2.SUP_PULSE)
        self._change(False, t_s, "pulse")
        return True

    def deadline_s(self) -> float | None:
        """When the heartbeat expires if no poll comes, or the pulse under way ends (None while off)."""
        if self.pulse_end_s is not None:
            return self.pulse_end_s
        return self.last_beat_s + self.timeout_s if self.on else None

    def _end_pulse(self, t_s: float) -> None:
        end, self.pulse_end_s = self.pulse_end_s, None
        if t_s - self.last_beat_s > self.timeout_s:  # the host fell silent meanwhile: off for good
            self._push(v2.CH_SUPERVISOR, self.last_beat_s + self.timeout_s,
                       round(self.timeout_s / self.pace * 1000.0), v2.SUP_HEARTBEAT)
            return
        self._push(v2.CH_SUPERVISOR, end, 0, v2.SUP_ON)
        self._change(True, end, "on")

    def service(self, t_s: float) -> None:
        """The main loop's check at ``t_s``: a heartbeat that expired before it drops the output then."""
        if self.pulse_end_s is not None:
            if t_s < self.pulse_end_s:
                return
            self._end_pulse(t_s)
        due = self.deadline_s()
        if due is not None and t_s >= due:
            self._push(v2.CH_SUPERVISOR, due, round(self.timeout_s / self.pace * 1000.0), v2.SUP_HEARTBEAT)
            self._change(False, due, "heartbeat")

    def period(self, tag: int, prev_edge_s: float, t_s: float, period_us: int) -> None:
        """An accepted Hall pulse at ``t_s`` ended a period of ``period_us`` begun at ``prev_edge_s``."""
        self.service(t_s)
        limit = self.min_period_us.get(tag, 0)
        pulsing = self.pulse_end_s is not None
        if (self.on or pulsing) and limit and prev_edge_s >= self.armed_at_s and period_us < limit:
            status = v2.SUP_OVERSPEED_PRIMARY if tag == v1.CH_PRIMARY else v2.SUP_OVERSPEED_SECONDARY
            self._push(v2.CH_SUPERVISOR, t_s, min(0xFFFF, period_us), status)
            self.pulse_end_s = None  # an over-speed during a pulse latches it off
            if self.on:
                self._change(False, t_s, v2.SUP_CAUSE_NAMES[status])
