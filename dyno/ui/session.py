"""A live test session for the UI: the backbone (poller, controller, run log) on the app's own loop.

Textual runs its own asyncio loop, so the simulated rig cannot use
:class:`dyno.clock.VirtualTimeLoop`.  Instead the session hands the composition root a scaled clock
(:class:`dyno.session.pacing.ScaledClock`, ``t_sim = (loop.time() - t0) * speed``) with the run's spec, and
:func:`dyno.session.root.build` paces the run from it.  The poller keeps its real-time rate.  The
controller times the plan on that clock, so the plan keeps its own durations (rig seconds: the warm-up,
steps, settling, measuring windows, the screen's "measuring N s"); the safety deadlines stay on the loop's.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass, field
from pathlib import Path

from dyno.control.api import State, TestPlan
from dyno.session.pacing import ScaledClock
from dyno.ui.rearm import RearmMixin

FINISHED = (State.DONE, State.ABORTED)


@dataclass(frozen=True)
class LiveOptions:
    """What a live session is to run (built by `dyno ui` or a test; frozen: the session hands the root a RunSpec)."""

    sim: bool = True
    speed: float = 1.0
    seed: int = 0
    out_dir: Path | None = None
    rig_path: Path | None = None
    calibration_path: Path | None = None
    engine_map_path: Path | None = None
    plan: TestPlan = field(default_factory=TestPlan)
    jog_s: float = 0.2  # one brake jog: actuator on-time, in rig (simulated) seconds
    drills: list = field(default_factory=list)  # dyno.session.drills.Drill (sim only), from the first frame
    mock_pins: bool = False  # sim: the physics driven through the real-rig output code (GpioActuators)
    firmware_elf: object = None  # sim: the Nano's real ELF in simavr as the rig's Nano (paced with the physics)
    ambient: object = None  # dyno.analysis.air.Ambient from --ambient (else rig.toml's sensor or day)
    sim_params: object = None  # dyno.sim.rig_params.RigParams (--sim-ideal, --sim-ambient, ...)


class LiveSession(RearmMixin):
    """Owns the run: start the tasks, forward the operator's commands, shut down safely."""

    def __init__(self, opts: LiveOptions) -> None:
        from dyno.session.root import RunSpec, build

        self.opts = opts
        loop = asyncio.get_running_loop()
        self.loop = loop
        self.speed = float(opts.speed) if opts.sim else 1.0
        self.clock = ScaledClock(loop.time, self.speed, held=True)  # the simulated rig's time, from start() (rig: unused)
        self.sim_now = self.clock.now
        paths = {k: v for k, v in (("calibration_path", opts.calibration_path),
                                   ("engine_map_path", opts.engine_map_path)) if v}
        run_opts = RunSpec(sim=opts.sim, seed=opts.seed, auto_go=False, out_dir=opts.out_dir,
                           rig_path=opts.rig_path, plan=opts.plan, clock=self.clock if opts.sim else None,
                           mock_pins=opts.sim and opts.mock_pins, ambient=opts.ambient,
                           drills=list(opts.drills) if opts.sim else [],  # (sim only)
                           firmware_elf=opts.firmware_elf if opts.sim else None,
                           sim_params=opts.sim_params if opts.sim else None,
                           listeners=(self._on_controller,), **paths)
        self._tasks: list[asyncio.Task] = []  # the controller's and the rest rate's (the polls: self.running's)
        self.closed = False
        self._after_task: asyncio.Task | None = None  # the ended test's release, zero, log and report (_end_test)
        self.state_since_s = loop.time()
        self.run_dir_removed = False  # set by close() when a simulated session never started a test
        self.started = False
        self.on_signal = None  # callable(exit_code) after a signal's abort (the app quits)
        # A hang-up while the rig is being built (run directory, pins, bus) must not kill the process with
        # the run log half-made: the handlers go in first, a signal that comes before the controller
        # exists waits for it (a run directory with a `start` record alone was left behind otherwise).
        # SIGTERM (systemd, kill), SIGHUP (terminal or SSH gone), SIGINT sent by ``kill -INT``: safe state, abort
        # record, exit 128+N (dyno.session.signals; the Ctrl+C *key* reaches a Textual app as a key: the E-STOP).
        import threading

        from dyno.session.signals import RunSignals

        self._signals = None
        if threading.current_thread() is threading.main_thread():
            self._signals = RunSignals(loop, closed="session closed", on_signal=self._on_hangup,
                                       after_abort=self._signal_to_app, record=False).install()
        try:
            self._build(opts, run_opts, build, loop)
        except BaseException:
            self._restore_signals()
            raise
        if self._signals is not None:
            self._signals.armed(self.ctx)

    def _build(self, opts, run_opts, build, loop) -> None:
        from dyno.session.running import RunningTest

        # the simulated rig paced from the scaled clock by the root: the controller's clock, actuators', polls, ring
        self.ctx = build(run_opts, self.sim_now if opts.sim else loop.time)
        # the test is run as `dyno run` runs it; on the rig with the guard of a long-lived face: the safe state on
        # SIGTERM and at exit (Ctrl+C reaches the app as a key, raw mode: the E-STOP)
        self.running = RunningTest(self.ctx, loop, exit_guard=True)
        self.poller = self.ctx.poller
        self.controller = self.ctx.controller
        self.manual = False
        self._jog_handle = None
        self._pause_points = 0
        # progress: when the controller last changed state (MEASURE's elapsed time), when each point arrived
        self.state_since_s = loop.time()
        self.run_dirs: list[Path] = [Path(self.ctx.writer.run_dir)]  # this session's runs, oldest first
        self._reports: list[asyncio.Task] = []  # report.html of re-armed-from runs, written in the background
        self._drills_fired_before = 0  # drills fired in earlier runs of the session (re-arm)
        self._closed_writer = None  # the run log closed last (each is closed once: at the test's end, or the quit)

    @property
    def t0(self) -> float:
        """The loop time the simulated rig's time starts from (the scaled clock's origin)."""
        return self.clock.t0

    @property
    def sim(self):
        return self.ctx.sim

    @property
    def actuators(self):
        """The rig's outputs (the simulated ones for ``is_safe``)."""
        return self.ctx.sim.actuators if self.ctx.sim is not None else self.controller.act

    def start(self) -> None:
        if self.closed or self.controller.state in FINISHED:  # (a signal during start-up: nothing starts)
            return
        self.started = True
        # The safety path does not depend on the UI: the watchdog is a thread, the checks run
        # in the poller and the controller's own heartbeat, drills act on the rig itself.
        self.running.start(before_first_poll=self._rig_time_zero if self.ctx.sim is not None else None)
        self._tasks = [self.running.start_controller()]

    def _rig_time_zero(self) -> None:
        """The simulated rig's time zero, in the same loop step as the poller's first poll (the test's start).

        The rig's time starts at the first poll, as a headless run's does: with ``restart`` the clock is set back
        to 0 here, so the building and the first screen take no rig time (rig time running through them lets the
        idling engine's edges and the ADC overfill the simulated Nano's 64-event ring, counted as lost before GO).
        """
        self.clock.restart()

    def _on_hangup(self, signum: int) -> None:
        import signal

        if signum == signal.SIGHUP:  # the terminal went: or Textual's shut-down may wait on it for ever
            from dyno.ui.common import detach_terminal

            detach_terminal()
            self.hung_up = True  # close at once: pads off the rotor, not the whole stroke (docs/safety.md)

    def _signal_to_app(self, signum: int) -> None:
        """After a signal's abort: the app quits with 128+N (asked again until it has hooked the session)."""
        if self.closed:
            return
        if self.on_signal is not None:
            self.on_signal(128 + signum)
        else:  # still not hooked: ask again (the abort is already done; only the app's exit waits)
            self.loop.call_later(0.05, self._signal_to_app, signum)

    def _restore_signals(self) -> None:
        if self._signals is not None:
            self._signals.restore()

    @property
    def finished(self) -> bool:
        return self.controller.state in FINISHED

    def _on_controller(self, controller) -> None:
        """Controller listener: every state change (and a discarded window, after which it measures again)."""
        self.state_since_s = self.loop.time()
        if controller.state in FINISHED and not any(t.get_name() == "rest-rate" for t in self._tasks):
            self._tasks.append(asyncio.create_task(self._idle_rate_at_rest(controller), name="rest-rate"))
        if controller.state in FINISHED and self._after_task is None and not self.closed:
            self._after_task = asyncio.create_task(self._end_test(controller), name="after-test")

    async def _end_test(self, ctrl) -> None:
        """A test has ended: what ``dyno run`` does after its test, through the same code
        (:mod:`dyno.session.after`): the release stroke serviced and, after DONE, the torque zero at rest; then the
        run's log closed with its summary and safety document, and its report.html written (in the background:
        matplotlib holds the GIL for seconds) while the screen stays up."""
        from dyno.session.after import end_test
        from dyno.ui.run_dirs import finish_in_background

        await end_test(self.ctx, poll_s=0.05)
        if ctrl is not self.controller or self.closed:
            return
        run_dir = Path(self.ctx.writer.run_dir)
        self._close_log()
        self._reports.append(asyncio.create_task(finish_in_background(run_dir), name="report"))

    @property
    def after_test_running(self) -> bool:
        """The ended test's release and zero reading are still under way (its log is still open)."""
        return self._after_task is not None and not self._after_task.done()

    async def _idle_rate_at_rest(self, ctrl) -> None:
        """A test has ended: full rate while the rig spins down and the brake releases (recorded as it
        happens; the polls service the release stroke), then the idle rate (``limits.armed_poll_hz``)
        until a re-arm — the screen left up after a test is idle CPU too.  The re-armed controller's
        first state sets the rate again."""
        from dyno.protocol import v1

        p = self.poller
        while ctrl is self.controller and ctrl.state in FINISHED:
            outs = self.actuators.output_states()
            if (outs.get("safe") and outs.get("brake_actuator") != "releasing"
                    and p.rpm(v1.CH_PRIMARY) == 0.0 and p.rpm(v1.CH_SECONDARY) == 0.0):
                p.set_poll_hz(ctrl.limits.armed_poll_hz)
                break
            await asyncio.sleep(0.5)
        self._tasks = [t for t in self._tasks if t.get_name() != "rest-rate"]

    def state_elapsed_s(self) -> float:
        """Rig seconds in the current state (the scaled clock: what MEASURE's limits are in)."""
        return (self.loop.time() - self.state_since_s) * self.speed

    def test_progress(self) -> tuple[int, int | None, float | None]:
        """(points so far, estimated total, real seconds left) of the running test: the headless
        progress line's estimate (:func:`dyno.control.progress.eta_now`) over the points' end times."""
        from dyno.control.progress import eta_now

        pts = self.controller.points
        ends = [p.get("host_t_end_s", math.nan) for p in pts]
        total, eta = eta_now(pts, ends, self.loop.time(), self.controller.plan)
        return len(pts), total, eta

    # --- operator commands ---------------------------------------------------------------
    def estop(self, source: str = "operator") -> None:
        self.cancel_jog()
        if self.finished:
            self.controller.latch_safe_state()  # again: an E-stop is never refused
            if not self.controller.aborts:
                self.controller.aborts.append({"cause": "estop", "detail": f"E-stop ({source}) after the test",
                                               "state": self.controller.state.value})
            return
        self.controller.estop(source)

    def go_refusal(self) -> str | None:
        """Why GO cannot be given now (None: it can)."""
        if self.controller.state is not State.ARMED:
            return f"GO only when armed (state: {self.controller.state.value})"
        driver_refusal = getattr(self.controller.act, "fault_refusal", None)  # the Pi's code: a standing fault
        why = driver_refusal() if callable(driver_refusal) else None
        return f"no GO: {why}" if why else None

    def go(self) -> str | None:
        """Start the armed test; returns why not, or None."""
        why = self.go_refusal()
        if why is None:
            self.controller.go()
        return why

    def toggle_pause(self) -> str:
        if self.finished:
            return "test finished"
        if self.controller.paused:
            self.controller.resume()
            return "stepping resumed"
        self.controller.pause()
        self._note_pause()
        return "stepping paused (after the current point)"

    def set_manual(self, on: bool) -> str:
        if on and self.finished:
            return "test finished: no manual mode"
        self.manual = on
        if on and not self.controller.paused:
            self.controller.pause()
            self._note_pause()
        if not on:
            self.cancel_jog()
        return "manual mode: [ release / ] apply jog the brake" if on else "manual mode off (p resumes stepping)"

    def jog(self, direction: int) -> str | None:
        """Move the brake actuator for ``jog_s``; returns why not, or None."""
        from dyno.control.outputs import STOP

        if not self.manual:
            return "jog only in manual mode (m)"
        if self.finished:
            return "test finished: the rig stays in its safe state"
        if not self._between_steps():
            return f"wait: the controller is in {self.controller.state.value} (pause takes effect after the point)"
        from dyno.errors import SafetyAbort

        self.cancel_jog()
        try:  # through the controller's gate, like a plan's commands
            self.controller.brake(direction)
        except SafetyAbort as exc:
            return str(exc)
        self._jog_handle = self.loop.call_later(self.opts.jog_s / self.speed, self.controller.brake, STOP)
        return None

    def _between_steps(self) -> bool:
        """True when a jog cannot disturb a step or a measurement.

        A paused controller only stops at the top of its step loop, after the
        point in progress, still showing that point's state; so a jog is allowed
        before the stepping starts, or once a point has completed since the pause.
        (A controller flag "waiting for resume" would make this exact.)
        """
        c = self.controller
        if c.state in (State.WAIT_ENGINE, State.ARMED, State.WARMUP):
            return True
        return c.paused and len(c.points) > self._pause_points

    def _note_pause(self) -> None:
        self._pause_points = len(self.controller.points)

    def cancel_jog(self) -> None:
        from dyno.control.outputs import STOP

        if self._jog_handle is not None:
            self._jog_handle.cancel()
            self._jog_handle = None
            self.controller.brake(STOP)  # (refused after the safe state: the release runs on)

    def _close_log(self) -> bool:
        """End the run's log as ``dyno run`` does (:func:`dyno.session.after.close_run`: the air after the run,
        the ``safety`` document with drill records, true-time latencies and the physical outputs, the end
        record); once per run: False when it was closed already (at the test's end)."""
        from dyno.session.after import close_run

        writer = self.ctx.writer
        if writer is self._closed_writer:
            return False
        self._closed_writer = writer
        try:
            close_run(self.ctx, drills_from=self._drills_fired_before)
        except Exception:  # noqa: BLE001 - the log is closed, its safety document says why the summary is missing
            pass
        return True

    async def close(self, why: str = "operator quit") -> None:
        """Safe state first, then stop the tasks and close the run log."""
        if self.closed:
            return
        self.closed = True
        self.cancel_jog()
        self.controller.latch_safe_state()
        if not self.finished:
            self.controller.abort("quit", why)
        if self.after_test_running:  # a quit while the ended test's zero was read: the release goes on below
            self._after_task.cancel()
            await asyncio.gather(self._after_task, return_exceptions=True)
        from dyno.session.safe_outputs import finish_release, release_done

        if (self.ctx.sim is not None and self.started and self.ctx.writer is not self._closed_writer
                and (self.controller.go_s is not None or not release_done(self.ctx))):
            # the simulated brake releases while the polls still advance its physics, so the run records
            # where it ended (the rig's own release is finished by its SafetyGuard on the way out); also
            # before GO: a safe state entered then (a watchdog trip when re-armed) powers the stroke too,
            # and a quit at once recorded it still "releasing" (rig_safe false, the pads never on the rotor)
            await finish_release(self.ctx, poll_s=0.05, pads_only=getattr(self, "hung_up", False))
        await self.running.stop(cancel=self._tasks)  # the polls, the controller, the drills, the watchdog
        self._restore_signals()
        self._close_log()
        if self._reports:  # the re-armed-from runs' reports (usually long done)
            await asyncio.wait(self._reports, timeout=60.0)
        self.running.release_guard()  # (the rig's: its release stroke finished, the pins released)
        if self.ctx.twin is not None:  # --mock-pins: release the mock pins (the record is closed)
            from dyno.session.safety import close_twin

            close_twin(self.ctx)
        if self.ctx.sim is not None:  # (--firmware-elf: the simavr harness ends with the session)
            self.ctx.sim.close()
        if getattr(self, "hung_up", False):  # safe state reached, record closed: should the app's shut-down
            from dyno.ui.common import exit_after  # still wait on the terminal that went, end anyway

            exit_after(128 + 1, grace_s=0.8)
        if self._nothing_ran():
            # A simulated session closed before GO records nothing worth keeping: no empty run
            # directory left behind.  (On the rig the directory always stays: it is where an
            # abort would have been recorded, and the engine may have run.)
            import shutil

            shutil.rmtree(self.ctx.writer.run_dir, ignore_errors=True)
            self.run_dir_removed = True
            self.run_dirs.remove(Path(self.ctx.writer.run_dir))

    def _nothing_ran(self) -> bool:
        c = self.controller
        if self.opts.sim and not self.started:  # closed (a signal) before the rig's first poll: nothing ran
            return True
        return (self.opts.sim and c.go_s is None and all(a.get("cause") == "quit" for a in c.aborts)
                and not (self.ctx.drills is not None and len(self.ctx.drills.fired) > self._drills_fired_before))
