"""Acknowledge an ended test and re-arm: a new run on the same rig, in the same UI session.

A mixin of :class:`dyno.ui.session.LiveSession` (its poller, controller, context and loop): the re-arm
checks, the new run's log and controller, and what the long-lived session must forget between runs.
"""

from __future__ import annotations

import asyncio
import json
import shutil
from pathlib import Path

from dyno.control.controller import State
from dyno.ui.run_dirs import _finish_in_background, _next_run_dir

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
        from dyno.control.controller import TestController
        from dyno.errors import DynoError
        from dyno.runlog.writer import RunWriter

        old, old_writer = self.controller, self.ctx.writer
        old_dir = Path(old_writer.run_dir)
        new_dir = _next_run_dir(old_dir, self.opts.out_dir)
        try:  # first the new log: if it cannot be written, nothing changes
            meta = json.loads((old_dir / "meta.json").read_text())
            for k in ("software_version", "created_unix_s", "format"):
                meta.pop(k, None)
            meta["rearmed_after"] = str(old_dir)
            engine_map = old.engine_map
            if self.ctx.ambient_sensor is not None:  # each run its own air, read when it is armed
                from dyno.session.ambient import read_sensor

                amb = read_sensor(self.ctx.ambient_sensor, "BME280")
                engine_map = engine_map.at_ambient(amb.temp_c, amb.dry_pressure_kpa)
                meta["ambient"] = amb.to_dict()
            tune = old_dir / "tune.toml"
            writer = RunWriter(new_dir, meta, calibration=old.calibration.to_dict(),
                               engine_map_text=(old_dir / "engine_map.csv").read_text(),
                               tune_text=tune.read_text() if tune.is_file() else None)
            for name in INPUT_COPIES:  # any other input the run keeps beside its log (e.g. its plan file)
                if (old_dir / name).is_file() and not (new_dir / name).exists():
                    shutil.copy2(old_dir / name, new_dir / name)
        except (DynoError, OSError, ValueError) as exc:
            return None, f"not re-armed: new run directory {new_dir}: {exc}"
        self.cancel_jog()
        self.manual = False
        clear = getattr(old.act, "clear_latch", None)
        if clear is not None:  # the explicit re-arm: the released rig accepts commands again
            clear()
        rearm_nano = getattr(self.poller.reader, "rearm_supervisor", None)
        if rearm_nano is not None:  # the Nano latched its run-enable off after a drop: the limits again
            rearm_nano()
        reported = not self._close_log()  # (closed at the test's end: its report.html is already under way)
        self.poller.listeners.remove(old_writer.events)
        self.poller.listeners.remove(old._on_poll)  # an ended controller checks nothing, but costs a call
        self.ctx.ambient = dict(meta.get("ambient") or {})
        ctrl = TestController(self.poller, old.act, old.calibration, engine_map, plan=old.plan,
                              limits=old.limits, writer=writer, auto_go=False, on_wait_engine=old.on_wait_engine,
                              runner_for=old.runner_for, from_idle=old.from_idle,
                              # what the composition root gave the first controller (dyno.session.root.build): the same
                              **{name: getattr(old, name) for name in REBUILT_ATTRS},
                              point_hooks=old.point_hooks,  # (the simulated rig's truth: keyed by time, not by run)
                              result_hooks=old.result_hooks)  # (the characterisations' sim truths)
        ctrl.listeners.append(self._on_controller)
        writer.on_error = lambda exc: ctrl.abort(
            "disk_full", f"cannot write the run log ({exc.strerror or exc}: {getattr(exc, 'filename', '') or new_dir}): "
            "safe state; what was recorded before stays readable")
        self.poller.listeners.append(writer.events)
        self.ctx.writer, self.ctx.controller, self.controller = writer, ctrl, ctrl
        self._rehook_watchdog()
        self._trim_history()
        if self.ctx.drills is not None:
            self._drills_fired_before = len(self.ctx.drills.fired)
        self._pause_points = 0
        self.state_since_s = self.loop.time()
        self._tasks = [t for t in self._tasks if t.get_name() != "controller"]
        self._tasks.append(asyncio.create_task(ctrl.run(), name="controller"))
        self.run_dirs.append(new_dir)
        if not reported:
            self._reports.append(asyncio.create_task(_finish_in_background(old_dir), name="report"))
        self._after_task = None
        return new_dir, f"re-armed: new run {new_dir} (report of the last one: {old_dir / 'report.html'})"

    def _trim_history(self) -> None:
        """Forget the ended run's events and the sim's truth samples (kept: the last ``HISTORY_KEEP_S``).

        The poller and the simulated rig live as long as the session; without this each re-arm adds the
        last run's events (~10 bytes each, a few hundred a second) to memory that no later run reads:
        the UI soak's RSS grew 17 % over two simulated hours.  The ended run is in its log by now.
        """
        dev_now_us = self.poller.device_now_us()
        if dev_now_us is not None:
            self.poller.streams.trim_before(int(dev_now_us - HISTORY_KEEP_S * 1e6))
        truth = getattr(self.ctx.sim, "truth", None)
        if truth is not None and len(truth.t):
            truth.trim_before(truth.t[-1] - HISTORY_KEEP_S)
        from dyno.session.heap import return_free_heap

        return_free_heap()

    def _rehook_watchdog(self) -> None:
        """The watchdog's heartbeat aborts through the controller: hook it to the new one."""
        from dyno.session.safety import _WatchdogKick, make_watchdog, start_watchdog

        self.poller.listeners[:] = [fn for fn in self.poller.listeners if not isinstance(fn, _WatchdogKick)]
        ctx = self.ctx
        timeout_s = ctx.rig_cfg.actuator.watchdog_s
        if ctx.hw is None and self._stop_watchdog is not None:  # the session's own: a new one beside the new controller
            self._stop_watchdog()
        # (the rig's own watchdog thread runs on: it reports to the new controller)
        ctx.watchdog = make_watchdog(self.controller, self.poller, ctx.hw, ctx.estop, timeout_s, self.loop.time)
        if ctx.hw is None:
            self._stop_watchdog = start_watchdog(ctx, self.loop)


# What dyno.session.root.build gives a controller's constructor beside the plan and its parts (rig.toml's description,
# control gains and inertias, the tune, the input channel as tared): a re-armed controller is given the same.
# (clock: the paced session's scaled clock -- lost, a re-armed x4 session would time its plan in host seconds;
# input_channel: the live screen's T_in)
REBUILT_ATTRS = ("rig", "tune_path", "control", "inertia", "clock", "input_channel")
INPUT_COPIES = ("plan.toml",)

#: seconds of events and truth a re-arm keeps (more than any window or drill check looks back over)
HISTORY_KEEP_S = 120.0

# Aborts after which the session is not re-armed: a software or host fault wants a fresh start.
NO_REARM = {"watchdog": "the control loop stalled", "error": "the controller crashed",
            "safety_error": "the safety task failed", "disk_full": "the run log cannot be written",
            "signal": "the session is closing"}
