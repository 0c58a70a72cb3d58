"""Acknowledge an ended test and re-arm: a new run on the same rig, in the same UI session.

A mixin of :class:`dyno.ui.session.LiveSession` (its poller, controller, context and loop): the re-arm
checks, the new run's log and controller, and what the long-lived session must forget between runs.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

from dyno.control.api import State
from dyno.ui.run_dirs import finish_in_background, next_run_dir

FINISHED = (State.DONE, State.ABORTED)


class RearmMixin:
    # --- acknowledge + re-arm: a new run on the same rig ------------------------------------
    def rearm_refusal(self) -> str | None:
        """Why the rig cannot be re-armed now (None: it can).

        Only after a test has ended, with the outputs in their safe state, the engine
        stopped and no limit or plausibility check failing (rotor too hot, link lost, ...);
        never after a software fault (watchdog, crashed controller or safety task, a run
        log that cannot be written): those want a fresh start of ``dyno``.
        """
        c = self.controller
        if not self.finished:
            return f"re-arm only after a test has ended (state: {c.state.value}; E-STOP first)"
        if self.after_test_running:
            return "not re-armed yet: the brake is releasing and the torque zero is read at rest (a few seconds)"
        cause = c.aborts[-1]["cause"] if c.aborts else None
        if cause in NO_REARM:
            return f"not re-armed after {cause} ({NO_REARM[cause]}): quit and start dyno again"
        if self.ctx.watchdog is not None and getattr(self.ctx.watchdog, "tripped", False):
            return "not re-armed: the watchdog tripped: quit and start dyno again"
        driver_refusal = getattr(c.act, "rearm_refusal", None)  # the Pi's output code: its release, its wiring
        why = driver_refusal() if callable(driver_refusal) else None
        if why:
            return f"not re-armed: {why}"
        estop = getattr(self.ctx, "estop", None)
        if estop is not None and estop.is_open:
            return "not re-armed: the E-stop chain is open (release the E-stop button first)"
        outs = self.actuators.output_states()
        if getattr(self.actuators, "releasing", False) or outs.get("brake_actuator") == "releasing":
            return "not re-armed: the brake is still releasing (wait for the release stroke to end)"
        if not outs.get("safe"):
            return (f"not re-armed: the rig is not in its safe state (throttle {outs.get('throttle')}, engine "
                    f"{outs.get('engine_kill')}, brake {outs.get('brake_actuator')}): E-STOP")
        from dyno.protocol import v1

        rp = self.poller.rpm(v1.CH_PRIMARY)
        if rp > c.plan.engine_running_rpm:
            return f"not re-armed: the engine still turns ({rp:.0f} rpm): wait until it has stopped"
        trip = c.check_limits()
        if trip is not None:
            return f"not re-armed: {trip.cause}: {trip.detail}"
        return None

    def rearm(self) -> tuple[Path | None, str]:
        """Acknowledge the ended test and arm a new one in a new run directory.

        The ended run's log is closed (its abort record stays) and its report.html is
        written in the background; the poller, the rig and its safety keep running; the
        new controller starts from WAIT_ENGINE, which only re-enables the ignition (the
        engine is started by the operator, the test by GO).  Returns (new run dir, message);
        (None, why) if refused.
        """
        why = self.rearm_refusal()
        if why:
            return None, why
        from dyno.errors import DynoError
        from dyno.session.next_run import open_next_log

        old_dir = Path(self.ctx.writer.run_dir)
        new_dir = next_run_dir(old_dir, self.opts.out_dir)
        try:  # first the new log: if it cannot be written, nothing changes
            log = open_next_log(self.ctx, old_dir, new_dir)
        except (DynoError, OSError, ValueError) as exc:
            return None, f"not re-armed: new run directory {new_dir}: {exc}"
        self.cancel_jog()
        self.manual = False
        old = self.controller
        clear = getattr(old.act, "clear_latch", None)
        if clear is not None:  # the explicit re-arm: the released rig accepts commands again
            clear()
        rearm_nano = getattr(self.poller.reader, "rearm_supervisor", None)
        if rearm_nano is not None:  # the Nano latched its run-enable off after a drop: the limits again
            rearm_nano()
        reported = not self._close_log()  # (closed at the test's end: its report.html is already under way)
        ctrl = self.running.rearm(log, listeners=(self._on_controller,))
        self.controller = ctrl
        self._trim_history()
        if self.ctx.drills is not None:
            self._drills_fired_before = len(self.ctx.drills.fired)
        self._pause_points = 0
        self.state_since_s = self.loop.time()
        self._tasks = [t for t in self._tasks if t.get_name() != "controller"]
        self._tasks.append(self.running.start_controller())
        self.run_dirs.append(new_dir)
        if not reported:
            self._reports.append(asyncio.create_task(finish_in_background(old_dir), name="report"))
        self._after_task = None
        return new_dir, f"re-armed: new run {new_dir} (report of the last one: {old_dir / 'report.html'})"

    def _trim_history(self) -> None:
        """Forget the ended run's events and the sim's truth samples (kept: the last ``HISTORY_KEEP_S``).

        The poller and the simulated rig live as long as the session; without this each re-arm adds the
        last run's events (~10 bytes each, a few hundred a second) to memory that no later run reads.
        The ended run is in its log by now.
        """
        dev_now_us = self.poller.device_now_us()
        if dev_now_us is not None:
            self.poller.streams.trim_before(int(dev_now_us - HISTORY_KEEP_S * 1e6))
        truth = getattr(self.ctx.sim, "truth", None)
        if truth is not None and len(truth.t):
            truth.trim_before(truth.t[-1] - HISTORY_KEEP_S)
        from dyno.session.heap import return_free_heap

        return_free_heap()


#: seconds of events and truth a re-arm keeps (more than any window or drill check looks back over)
HISTORY_KEEP_S = 120.0

# Aborts after which the session is not re-armed: a software or host fault wants a fresh start.
NO_REARM = {"watchdog": "the control loop stalled", "error": "the controller crashed",
            "safety_error": "the safety task failed", "disk_full": "the run log cannot be written",
            "signal": "the session is closing"}
