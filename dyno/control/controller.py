"""The steady-state test: a plan executed through an explicit state table.

::

    IDLE -> WAIT_ENGINE -> ARMED --GO--> WARMUP -> STEP -> SETTLE -> MEASURE -+-> STEP ...
                                                                              +-> DONE
    any state --(E-stop, over-temperature, lost link, over-speed, error)--> ABORTED

The controller never touches pins or bytes: it reads the poller's live values
and streams and drives an :class:`~dyno.control.outputs.Actuators`.  A separate
safety task checks the limits every ``check_period_s`` (20 ms); any trip puts the
actuators in the safe state at once (throttle idle, engine killed, brake
released) and logs the cause with the trigger and safe-state times.
"""

from __future__ import annotations

import asyncio
import math

# The dependency runs one way: this engine and the plan runners are siblings that meet at
# dyno.control.api (State, TestPlan are defined there), and no plan module imports this one.  Nor does this module import dyno.control.plans: the plan modes' runners are handed in
# (``runner_for``/``from_idle``, as the app's composition root does); the default is the mode table in
# dyno.control.registry, a leaf over the api that imports a runner's module only when its mode runs.
from dyno.clock import LOOP_RIG_CLOCK
from dyno.control import registry as _registry
from dyno.control.api import ENGINE_STATES as _ENGINE_STATES
from dyno.control.api import LOADED_STATES as _LOADED_STATES
from dyno.control.api import TRANSITIONS, State, TestPlan
from dyno.control.engine import EngineContext
from dyno.control.kill_probe import prove_kill_chain
from dyno.control.measuring import Measuring
from dyno.control.outputs import APPLY, DeadlineService, enter_safe_state, ignition_hold_ended
from dyno.control.safety import SafetyLimits, SafetyMonitor, Trip
from dyno.errors import SafetyAbort
from dyno.protocol import v1

__all__ = ["TestController"]


class TestController(Measuring):
    def __init__(self, poller, actuators, calibration, engine_map, *, plan: TestPlan = TestPlan(),
                 limits: SafetyLimits = SafetyLimits(), writer=None, auto_go: bool = False,
                 on_wait_engine=None, runner_for=None, from_idle=None, rig=None, tune_path=None, shift_prediction=None,
                 control=None, inertia=None, input_channel=None, clock=None,
                 point_hooks=(), result_hooks=(), listeners=(), heartbeat_hooks=()) -> None:
        # Everything the composition root (dyno.session.root.build) wires is given here, never set afterwards
        # (tests/test_layers.py checks that no module assigns to a built controller's attributes).
        self.poller = poller
        self.act = actuators
        self.calibration = calibration  # tared at the zero read before GO (self.tare: the record)
        self.tare: dict | None = None
        self.engine_map = engine_map
        self.plan = plan
        self.limits = limits
        self.writer = writer
        self.auto_go = auto_go
        self.on_wait_engine = on_wait_engine  # e.g. the simulated operator pulls the cord
        # The plan modes: mode -> coroutine function(plan context), and the modes whose
        # runner starts from idle right after GO (no warm-up). Default: dyno.control.registry's table.
        self.runner_for = runner_for if runner_for is not None else _registry.runner_for
        self.from_idle = from_idle if from_idle is not None else _registry.FROM_IDLE
        self.state = State.IDLE
        self.reason = ""
        self.points: list[dict] = []
        self.aborts: list[dict] = []
        # rig.toml's description, [control] gains and [inertia] (the plans read them: dyno.control.api.PlanConfig),
        # the tune a characterisation compares with, the engine-side torque channel (or None; tared at GO)
        self.rig, self.control, self.inertia = rig, control, inertia
        self.tune_path = tune_path  # (the faces' overlay reads it; a plan gets ``shift_prediction``)
        self.shift_prediction = shift_prediction  # the tune's predicted shift (dyno.control.api.ShiftPrediction)
        self.input_channel = input_channel
        #: the run's clock: rig time (``now()``, ``await sleep(rig_s)``) for everything the plan times (its
        #: durations, the runners' hold periods and approach times, settling, measuring windows); the loop's
        #: own clock unless a paced live session hands its scaled clock (dyno.session.pacing.ScaledClock).
        #: The safety deadlines (heartbeat, link timeout, watchdog) and the log's host times stay on the loop.
        self.clock = clock if clock is not None else LOOP_RIG_CLOCK
        self.point_hooks: list = list(point_hooks)  # callables(point, host_t0_s, host_t1_s) -> None
        self.listeners: list = list(listeners)  # callables(controller) on every state change
        self.paused = False
        self._go = asyncio.Event()
        self._resume = asyncio.Event()
        self._resume.set()
        self._aborted = asyncio.Event()
        cal = calibration
        torque_from_code = None
        if cal is not None and getattr(cal, "slope_counts_per_nm", 0):
            def torque_from_code(code: float) -> float:
                return (code - cal.intercept_counts) / cal.slope_counts_per_nm
        self.monitor = SafetyMonitor(limits, poller, torque_from_code)
        self.heartbeat_hooks: list = list(heartbeat_hooks)  # callables() on every safety heartbeat (the watchdog's feed)
        self.discards: list[dict] = []
        self.skips: list[str] = []  # why a setpoint or step gave no point (each also a "skip" document)
        self.engine_cut = False  # a coast-down cut the engine on purpose: Hall checks stop expecting it
        self.results: dict = {}  # a characterisation plan's figures (dyno.control.plans.characterise / coastdown)
        self.result_hooks: list = list(result_hooks)  # callables(results) -> None (the sim adds its truths)
        self.go_s: float | None = None  # host (loop) time of GO
        self.go_rig_s: float | None = None  # rig time of GO (test_time_s counts from it)
        self.load_since_s: float | None = None  # rig time the brake first loaded the CVT (warm-up criterion)
        self.warmup: dict | None = None  # the warm-up criterion as met (a `warmup` document too)
        self.fault_injection: BaseException | None = None  # drill controller-crash: raised in the plan task
        self._checking = False
        self._silence: asyncio.Future | None = None  # the heartbeat task's wait; set while run() runs
        self._silence_timer: asyncio.TimerHandle | None = None
        self._output_deadlines = DeadlineService()  # the release sequenced at the driver's deadlines
        self._last_beat_s = -math.inf
        # The throttle as last commanded (the Actuators interface has no read-back): every point records
        # it (``throttle_frac``) and takes its efficiency from the engine map's curve at that throttle.
        self.throttle_frac = 0.0
        # The engine's gate: closed by every safe state the controller commands after a trip or at the
        # end of the test; from then on the plans' output calls are refused (and logged), whatever the
        # actuators themselves latch. Only a new controller (a re-arm) starts open.
        self.outputs_latched = False
        self.refused: list[dict] = []
        self.kill_probe: dict = {}  # the kill chain's proof before GO (dyno.control.kill_probe): each path's dip
        poller.listeners.append(self._on_poll)
        self.plan_context = EngineContext(self)  # all a plan runner is handed (dyno.control.api.PlanContext)

    def detach(self) -> None:
        """Stop listening to the poller (an ended controller a re-arm replaces: dyno.session.next_run)."""
        self.poller.listeners[:] = [fn for fn in self.poller.listeners if fn != self._on_poll]

    # --- commands (from the UI / CLI) ------------------------------------------------------
    def go(self) -> None:
        self._go.set()

    def pause(self) -> None:
        self.paused = True
        self._resume.clear()
        self._log("pause")

    async def wait_resumed(self) -> None:
        """Return when the operator has not paused the test."""
        await self._resume.wait()

    def host_now(self) -> float:
        """Host (loop) seconds: the time base of the log and of the points' windows."""
        return self._now()

    def resume(self) -> None:
        self.paused = False
        self._resume.set()
        self._log("resume")

    def set_throttle(self, fraction: float, *, log: bool = True) -> None:
        """Command the throttle (0 idle .. 1 full) and remember it for the points (logged as ``throttle``
        unless ``log`` is False: a ramp's every tick). Refused (SafetyAbort) after the safe state."""
        if self.outputs_latched and fraction > 0:
            self._refuse("throttle", float(fraction))
        self.act.throttle(fraction)
        self.throttle_frac = min(1.0, max(0.0, float(fraction)))
        if log:
            self._log("throttle", throttle_frac=self.throttle_frac)

    # --- the plans' outputs: every actuator call a plan makes passes the gate --------------------------
    def brake(self, direction: int) -> None:
        """Move the brake actuator (APPLY/RELEASE) or stop it (STOP), as a plan or the operator asks.

        After a safe state has been commanded nothing here reaches the actuator: STOP and RELEASE are
        refused quietly (logged as ``refused``: a plan's cleanup must not stop the release stroke), APPLY
        raises :class:`~dyno.errors.SafetyAbort` (the caller must not believe it is loading the rig).
        """
        if self.outputs_latched:
            self._refuse("brake", int(direction), hard=direction == APPLY)
            return
        self.act.brake(direction)

    def cut_engine(self) -> None:
        """A deliberate engine cut (coast-down): ignition off, throttle idle, brake released — the safe
        state's outputs without its latch, and the Hall checks stop expecting the engine."""
        self.engine_cut = True
        enter_safe_state(self.act, latch=False)
        self._output_deadlines.start(self.act, self.time_scale)
        self.throttle_frac = 0.0
        self._log("engine_cut")

    def _refuse(self, what: str, value, hard: bool = True) -> None:
        entry = {"command": what, "value": value, "state": self.state.value}
        try:
            entry["t_s"] = self._now()
        except RuntimeError:
            entry["t_s"] = math.nan
        self.refused.append(entry)
        self._log("refused", **entry)
        if hard:
            raise SafetyAbort(f"{what} refused: the rig is in its safe state (latched until re-armed)")

    def latch_safe_state(self) -> None:
        """The engine's last word: the safe state, latched (actuators and this controller's gate)."""
        enter_safe_state(self.act, latch=True)
        self._output_deadlines.start(self.act, self.time_scale)
        self.outputs_latched = True
        self.throttle_frac = 0.0

    def estop(self, source: str = "operator") -> None:
        self.abort("estop", f"E-stop ({source})")

    # --- state machine -------------------------------------------------------------------------
    def _now(self) -> float:
        return asyncio.get_running_loop().time()

    def _enter(self, new: State, reason: str = "") -> None:
        if new not in TRANSITIONS[self.state]:
            raise RuntimeError(f"illegal transition {self.state.value} -> {new.value}")
        self.state = new
        self.reason = reason
        self._set_poll_rate()
        self._log("state", state=new.value, reason=reason)
        for fn in self.listeners:
            fn(self)

    def _set_poll_rate(self) -> None:
        """The waiting states (WAIT_ENGINE: for the operator to start the engine; ARMED: for GO) poll at
        ``limits.armed_poll_hz`` — the idle CPU; every other state at the full rate."""
        set_hz = getattr(self.poller, "set_poll_hz", None)
        if set_hz is not None:
            set_hz(self.limits.armed_poll_hz if self.state in (State.WAIT_ENGINE, State.ARMED) else None)

    def _log(self, doc_type: str, **fields) -> None:
        if doc_type == "skip":
            self.skips.append(str(fields.get("reason", "")))
        if self.writer is not None:
            try:
                t = self._now()
            except RuntimeError:
                t = math.nan
            self.writer.doc(doc_type, host_t_s=t, device_t_us=self.poller.device_now_us(), **fields)

    def abort(self, cause: str, detail: str, trigger_s: float | None = None, *, after_done: bool = False,
              **fields) -> None:
        """Safe state now, then record why. Idempotent.

        ``trigger_s`` is when the condition became true (e.g. the thermometer
        reading over the limit, or the moment the link timeout expired); the
        log keeps it with the time the safe state was commanded.
        """
        if self.state in (State.ABORTED,):
            return
        now = self._now()
        self.latch_safe_state()  # first, before any bookkeeping
        safe_s = self._now()
        trigger_s = now if trigger_s is None else trigger_s
        entry = {"cause": cause, "detail": detail, "state": self.state.value, "trigger_s": trigger_s,
                 "safe_state_s": safe_s, "latency_s": safe_s - trigger_s, **fields}
        self.aborts.append(entry)
        self._log("abort", **entry)
        if self.state is not State.DONE:
            self._enter(State.ABORTED, detail)
        elif after_done:  # the plan ended, but what it produced is not a result
            self.state = State.ABORTED
            self._set_poll_rate()
            self.reason = detail
            self._log("state", state=State.ABORTED.value, reason=detail)
            for fn in self.listeners:
                fn(self)
        self._aborted.set()

    async def run(self) -> State:
        """Run the plan to DONE or ABORTED.

        Three tasks: the plan, the safety heartbeat, and the wait for an abort.  The
        safety checks also run after every poll (:meth:`_on_poll`), so detection does
        not wait for the heartbeat; the heartbeat keeps checking if polls stop, feeds
        the watchdog, and if it ever dies the test aborts (never runs unmonitored).
        """
        safety = asyncio.create_task(self._safety_loop(), name="safety")
        plan_task = self._plan_task = asyncio.create_task(self._plan_guarded(), name="plan")
        aborted = asyncio.create_task(self._aborted.wait())
        try:
            while True:
                done, _ = await asyncio.wait({plan_task, aborted, safety}, return_when=asyncio.FIRST_COMPLETED)
                if plan_task in done and not plan_task.cancelled() and plan_task.exception() is not None:
                    exc = plan_task.exception()
                    self.abort("error", f"controller error: {type(exc).__name__}: {exc}")
                elif safety in done and self.state not in (State.DONE, State.ABORTED):
                    exc = None if safety.cancelled() else safety.exception()
                    why = f"{type(exc).__name__}: {exc}" if exc is not None else "stopped"
                    self.abort("safety_error", f"safety task died ({why}): the rig is not run unmonitored")
                if plan_task in done or aborted in done or self.state in (State.DONE, State.ABORTED):
                    break
        except BaseException:
            self.latch_safe_state()
            raise
        finally:
            for t in (plan_task, aborted, safety):
                t.cancel()
            await asyncio.gather(plan_task, aborted, safety, return_exceptions=True)
            await self.plan_context.end_holds()  # a hold the plan left running
            # The engine has the last word, after the plan's cleanup: whatever the plan did on its way
            # out, the outputs are in the latched safe state (a release already under way keeps going).
            if self.state is State.ABORTED and not getattr(self.act, "latched", False):
                self.latch_safe_state()
        if self.state not in (State.DONE, State.ABORTED):
            # The plan task ended (returned, or was cancelled and swallowed it) without finishing the test:
            # never leave the rig running as it was (a crash injected mid-measure, bench/bench_safety.py).
            # (an injected crash may have been raised in a plan's helper task, e.g. the speed hold's loop,
            # while the plan task itself was cancelled)
            crash, self.fault_injection = self.fault_injection or self._injected, None
            why = (f"controller error: {type(crash).__name__}: {crash}" if crash is not None
                   else f"the plan ended in state {self.state.value} without finishing the test")
            self.abort("error", why)
        if self.state is State.DONE:
            self.latch_safe_state()  # end of test: same safe state, not an abort
            if not self.points and not self.results:
                # A test that measured nothing is not a success, whatever the plan's end says.
                self.abort("no_points", "the test ended without a single accepted point", after_done=True)
        return self.state

    async def _plan_guarded(self) -> None:
        try:
            await self._plan()
        except asyncio.CancelledError:
            if self.fault_injection is not None:  # drill controller-crash: the task raises now
                exc, self.fault_injection = self.fault_injection, None
                raise exc from None
            raise

    def inject_crash(self, exc: BaseException) -> None:
        """Drill ``controller-crash``: the control task raises ``exc`` at once."""
        self.fault_injection = self._injected = exc
        task = getattr(self, "_plan_task", None)
        if task is not None and not task.done():
            task.cancel()

    _injected: BaseException | None = None  # the last crash injected (drill controller-crash)

    def tare_input(self, channel) -> None:
        """The engine-side channel with its zero from GO's window (dyno.session.input_channel's first point)."""
        self.input_channel = channel

    def set_zero_check(self, check: dict, input_check: dict | None = None) -> None:
        """The zero at rest after the test (dyno.control.zero_check.after_test), and the input channel's."""
        self.zero_check = check
        if input_check is not None:
            self.zero_check_input = input_check

    @property
    def time_scale(self) -> float:
        """Host seconds per rig second: 1, except in a paced live session (speed N: 1/N)."""
        return 1.0 / self.clock.speed

    def rig_now(self) -> float:
        """The controller's time in rig seconds (:attr:`clock`)."""
        return self.clock.now()

    async def rig_sleep(self, dt_s: float) -> None:
        """Wait ``dt_s`` rig seconds (a duration of the plan's), the outputs serviced after."""
        await self.clock.sleep(dt_s)
        self._after_sleep()

    async def _sleep(self, dt_s: float) -> None:
        """Wait ``dt_s`` host (loop) seconds: the poller's and the link's own periods."""
        await asyncio.sleep(dt_s)
        self._after_sleep()

    def _after_sleep(self) -> None:
        if self.fault_injection is not None:
            exc, self.fault_injection = self.fault_injection, None
            raise exc
        self.act.tick(self._now())

    def _tare(self) -> None:
        """The points measure torque from the zero just read at rest (rig.toml [torque_zero] tare)."""
        from dyno.analysis.zero_check import tare
        from dyno.control.zero_check import zero_config

        if not zero_config(self).tare:
            return
        self.calibration, rec = tare(self.calibration, self.zero_before)
        if rec is not None:
            self.tare = rec
            self.zero_before = {**self.zero_before, "torque_nm": 0.0, "tared_from_nm": rec["zero_nm"]}
            self._log("tare", **rec)

    async def _plan(self) -> None:
        p = self.plan
        enter_safe_state(self.act, latch=False)  # the start of a run (the brake position is not known)
        self.throttle_frac = 0.0
        if not await ignition_hold_ended(self):  # (dyno.control.outputs: the start-up release's full stroke)
            return
        self._enter(State.WAIT_ENGINE, f"start the engine (primary > {p.engine_running_rpm:.0f} rpm)")
        self.act.engine_kill(False)
        if self.on_wait_engine:
            self.on_wait_engine()
        since = None
        t_enabled = self.rig_now()  # the plan's durations are rig seconds (self.clock)
        while True:
            await self.rig_sleep(0.05)
            if self.rig_now() - t_enabled > p.engine_start_timeout_s:
                self.abort("stall", f"no engine speed {p.engine_start_timeout_s:.0f} s after enabling the ignition: "
                                    "engine not started, or the primary Hall sensor is dead")
                return
            if self.poller.rpm(v1.CH_PRIMARY) > p.engine_running_rpm:
                since = since if since is not None else self.rig_now()
                if self.rig_now() - since >= p.engine_detect_s:
                    break
            else:
                since = None
        self._enter(State.ARMED, "engine running; press GO to start")
        from dyno.control.zero_check import read_zero

        self.zero_before = await read_zero(self)  # torque zero at rest (idle is below engagement)
        self._tare()
        # every path that can cut the engine, opened briefly at idle before GO (docs/safety.md): one that does
        # not cut ends the test here, before any load
        if not (await prove_kill_chain(self, self.kill_probe))["ok"]:
            return
        if self.auto_go:
            self._go.set()
        await self._go.wait()
        self.go_s, self.go_rig_s = self._now(), self.rig_now()
        if p.mode in self.from_idle:  # characterisations start from idle: no full-throttle warm-up
            await self.runner_for(p.mode)(self.plan_context, _registry.params_of(p))
            return
        self._enter(State.WARMUP, "full throttle, no brake")
        self.set_throttle(1.0)
        await self.rig_sleep(p.warmup_s)
        await self.runner_for(p.mode)(self.plan_context, _registry.params_of(p))

    # --- safety ----------------------------------------------------------------------------------
    def _on_poll(self, events, now_s: float) -> None:
        """Poller listener: the checks run on fresh data; while :meth:`run` runs, each poll is also the
        heartbeat (outputs serviced, watchdog fed) and re-arms the heartbeat's own timer for when polls stop.
        After the test has ended the polls still service the outputs: the safe state's release stroke
        ends (and the actuator is de-energised) though the heartbeat has stopped with the test."""
        self._safety_check(now_s)
        running = self._silence is not None and not self._silence.done()
        if not running and self.state not in (State.DONE, State.ABORTED):
            return
        # The beat keeps the heartbeat's cadence (every 3rd poll at 150 Hz, every poll at the ARMED 50 Hz): the
        # real rig's relay/enable sequencing is serviced on beats, and the brake pulses were tuned on it.
        now = self._now() if now_s is None else now_s
        if now - self._last_beat_s >= 0.75 * self.limits.check_period_s:
            if running:
                self._beat()
            else:
                self._last_beat_s = now
                self.act.tick(now)
        if running:
            self._arm_silence_timer(after_poll=True)

    def _beat(self) -> None:
        self._last_beat_s = now = self._now()
        self.act.tick(now)
        for hook in self.heartbeat_hooks:
            hook()

    def _safety_check(self, now_s: float | None = None) -> None:
        if self._checking or self.state in (State.DONE, State.ABORTED, State.IDLE):
            return
        self._checking = True
        try:
            now = self._now() if now_s is None else now_s
            trip = self.monitor.check(now, loaded=self.state in _LOADED_STATES and not self.engine_cut,
                                      engine_expected=self.state in _ENGINE_STATES and not self.engine_cut)
        except Exception as exc:  # a broken check must not leave the rig unmonitored
            self._checking = False
            self.abort("safety_error", f"safety check failed: {type(exc).__name__}: {exc}")
            return
        self._checking = False
        if trip:
            self.abort(trip.cause, trip.detail, trip.trigger_s)

    def _arm_silence_timer(self, after_poll: bool = False) -> None:
        """(Re)start the heartbeat's timer: ``check_period_s`` from now, plus one poll period after a poll.

        One loop timer moved on every poll (a heap push) instead of a task waking every period: while
        polls flow the heartbeat costs no wake-up of its own, which is most of the idle CPU (issue 13).
        The poll period's allowance keeps a poll a little late (or a slow ARMED rate) from waking it.
        """
        if self._silence_timer is not None:
            self._silence_timer.cancel()
        loop = self._silence.get_loop()
        wait_s = self.limits.check_period_s + (getattr(self.poller, "poll_period_s", 0.0) if after_poll else 0.0)
        self._silence_timer = loop.call_at(loop.time() + wait_s, self._end_silence)

    def _end_silence(self) -> None:
        """The heartbeat's timer fired: no poll for a whole period, wake its task."""
        if self._silence is not None and not self._silence.done():
            self._silence.set_result(None)

    async def _safety_loop(self) -> None:
        """The heartbeat when polls stop: outputs serviced, watchdog fed and the checks run
        ``check_period_s`` after the last beat.

        While polls flow each poll is the beat (:meth:`_on_poll`) and this task sleeps; when they stop
        (a hung bus, a blocked transfer) it beats every ``check_period_s`` and its checks find the link
        silent.  If the loop itself stops, nothing beats and the watchdog thread trips.
        """
        loop = asyncio.get_running_loop()
        try:
            while True:
                self._silence = loop.create_future()
                self._arm_silence_timer()
                await self._silence
                self._beat()
                if self.state not in (State.DONE, State.ABORTED):
                    self._safety_check()  # no poll ran one for a whole period
        finally:
            self._silence = None
            if self._silence_timer is not None:
                self._silence_timer.cancel()
                self._silence_timer = None

    def check_limits(self) -> Trip | None:
        """The first limit or plausibility check failing now, or None (see SafetyMonitor)."""
        return self.monitor.check(self._now(), loaded=self.state in _LOADED_STATES,
                                  engine_expected=self.state in _ENGINE_STATES)
