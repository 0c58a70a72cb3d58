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
import enum
import math
from dataclasses import dataclass, field

from dyno.analysis.points import reduce_point
from dyno.control.outputs import APPLY, STOP
from dyno.control.steady import SettleCriteria, is_settled
from dyno.protocol import v1


class State(enum.Enum):
    IDLE = "idle"
    WAIT_ENGINE = "wait_engine"
    ARMED = "armed"
    WARMUP = "warmup"
    STEP = "step"
    SETTLE = "settle"
    MEASURE = "measure"
    DONE = "done"
    ABORTED = "aborted"


TRANSITIONS: dict[State, set[State]] = {
    State.IDLE: {State.WAIT_ENGINE},
    State.WAIT_ENGINE: {State.ARMED},
    State.ARMED: {State.WARMUP},
    State.WARMUP: {State.STEP},
    State.STEP: {State.SETTLE},
    State.SETTLE: {State.MEASURE, State.DONE},
    State.MEASURE: {State.STEP, State.DONE},
    State.DONE: set(),
    State.ABORTED: set(),
}
for _s in State:
    if _s not in (State.DONE, State.ABORTED):
        TRANSITIONS[_s].add(State.ABORTED)


@dataclass(frozen=True)
class TestPlan:
    engine_running_rpm: float = 1300.0  # primary above this = engine started
    engine_detect_s: float = 0.5
    warmup_s: float = 3.0  # full throttle, no brake: let it stabilise
    step_s: float = 0.25  # brake actuator on-time per step (adapted, see below)
    step_min_s: float = 0.08
    step_max_s: float = 1.0
    target_points: int = 20  # adapt the step so the run gives about this many points
    measure_s: float = 3.0  # the thesis's 3 s average (the minimum)
    target_efficiency_sem: float = 0.0012  # extend the average until the standard error is this small ...
    max_measure_s: float = 24.0  # ... or this long (rotor heat limits how long a point can last)
    min_point_torque_nm: float = 4.0  # below this the brake has not really loaded the CVT: no point
    settle_mode: str = "detect"  # "detect" (from the data) or "fixed" (thesis: 4 s)
    settle: SettleCriteria = field(default_factory=SettleCriteria)
    min_secondary_rpm: float = 1500.0  # stop when the secondary falls below this
    max_points: int = 60
    expected_secondary_span_rpm: float = 4500.0  # light load to min, for the step adaptation


@dataclass(frozen=True)
class SafetyLimits:
    rotor_temp_max_c: float = 300.0
    overspeed_primary_rpm: float = 4300.0
    overspeed_secondary_rpm: float = 9000.0
    comms_timeout_s: float = 0.5
    thermometer_timeout_s: float = 2.0  # a blind over-temperature monitor is no monitor
    sensor_check_rpm: float = 300.0  # a shaft turning faster than this must give Hall edges
    check_period_s: float = 0.02  # detection latency <= 20 ms, well inside the 100 ms budget


_LOADED_STATES = {State.WARMUP, State.STEP, State.SETTLE, State.MEASURE}


class TestController:
    def __init__(self, poller, actuators, calibration, engine_map, *, plan: TestPlan = TestPlan(),
                 limits: SafetyLimits = SafetyLimits(), writer=None, auto_go: bool = False,
                 on_wait_engine=None) -> None:
        self.poller = poller
        self.act = actuators
        self.calibration = calibration
        self.engine_map = engine_map
        self.plan = plan
        self.limits = limits
        self.writer = writer
        self.auto_go = auto_go
        self.on_wait_engine = on_wait_engine  # e.g. the simulated operator pulls the cord
        self.state = State.IDLE
        self.reason = ""
        self.points: list[dict] = []
        self.aborts: list[dict] = []
        self.point_hooks: list = []  # callables(point, host_t0_s, host_t1_s) -> None
        self.listeners: list = []  # callables(controller) on every state change
        self.paused = False
        self._go = asyncio.Event()
        self._resume = asyncio.Event()
        self._resume.set()
        self._aborted = asyncio.Event()
        self._step_s = plan.step_s

    # --- commands (from the UI / CLI) ------------------------------------------------------
    def go(self) -> None:
        self._go.set()

    def pause(self) -> None:
        self.paused = True
        self._resume.clear()
        self._log("pause")

    def resume(self) -> None:
        self.paused = False
        self._resume.set()
        self._log("resume")

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
        self._log("state", state=new.value, reason=reason)
        for fn in self.listeners:
            fn(self)

    def _log(self, doc_type: str, **fields) -> None:
        if self.writer is not None:
            try:
                t = self._now()
            except RuntimeError:
                t = math.nan
            self.writer.doc(doc_type, host_t_s=t, device_t_us=self.poller.device_now_us(), **fields)

    def abort(self, cause: str, detail: str, trigger_s: float | None = None) -> None:
        """Safe state now, then record why. Idempotent.

        ``trigger_s`` is when the condition became true (e.g. the thermometer
        reading over the limit, or the moment the link timeout expired); the
        log keeps it with the time the safe state was commanded.
        """
        if self.state in (State.ABORTED,):
            return
        now = self._now()
        self.act.safe_state()  # first, before any bookkeeping
        safe_s = self._now()
        trigger_s = now if trigger_s is None else trigger_s
        entry = {"cause": cause, "detail": detail, "state": self.state.value, "trigger_s": trigger_s,
                 "safe_state_s": safe_s, "latency_s": safe_s - trigger_s}
        self.aborts.append(entry)
        self._log("abort", **entry)
        if self.state is not State.DONE:
            self._enter(State.ABORTED, detail)
        self._aborted.set()

    async def run(self) -> State:
        """Run the plan to DONE or ABORTED."""
        safety = asyncio.create_task(self._safety_loop())
        plan_task = asyncio.create_task(self._plan())
        aborted = asyncio.create_task(self._aborted.wait())
        try:
            done, _ = await asyncio.wait({plan_task, aborted}, return_when=asyncio.FIRST_COMPLETED)
            if plan_task in done and plan_task.exception() is not None:
                exc = plan_task.exception()
                self.abort("error", f"controller error: {type(exc).__name__}: {exc}")
        except BaseException:
            self.act.safe_state()
            raise
        finally:
            for t in (plan_task, aborted, safety):
                t.cancel()
            await asyncio.gather(plan_task, aborted, safety, return_exceptions=True)
        if self.state is State.DONE:
            self.act.safe_state()  # end of test: same safe state, not an abort
        return self.state

    async def _sleep(self, dt_s: float) -> None:
        await asyncio.sleep(dt_s)
        self.act.tick(self._now())

    async def _plan(self) -> None:
        p = self.plan
        self.act.safe_state()
        self._enter(State.WAIT_ENGINE, f"start the engine (primary > {p.engine_running_rpm:.0f} rpm)")
        self.act.engine_kill(False)
        if self.on_wait_engine:
            self.on_wait_engine()
        since = None
        while True:
            await self._sleep(0.05)
            if self.poller.rpm(v1.CH_PRIMARY) > p.engine_running_rpm:
                since = since if since is not None else self._now()
                if self._now() - since >= p.engine_detect_s:
                    break
            else:
                since = None
        self._enter(State.ARMED, "engine running; press GO to start")
        if self.auto_go:
            self._go.set()
        await self._go.wait()
        self._enter(State.WARMUP, "full throttle, no brake")
        self.act.throttle(1.0)
        await self._sleep(p.warmup_s)
        last_rs = self.poller.rpm(v1.CH_SECONDARY)
        while True:
            await self._resume.wait()
            self._enter(State.STEP, f"brake step {self._step_s * 1e3:.0f} ms")
            self.act.brake(APPLY)
            await self._sleep(self._step_s)
            self.act.brake(STOP)
            self._enter(State.SETTLE, "waiting for steady state")
            settled_by, settle_s = await self._settle()
            if self.poller.rpm(v1.CH_SECONDARY) < p.min_secondary_rpm:
                self._enter(State.DONE, f"secondary below {p.min_secondary_rpm:.0f} rpm")
                return
            self._enter(State.MEASURE, f"averaging {p.measure_s:.1f} s")
            host_t0, dev_t0 = self._now(), self.poller.device_now_us()
            await self._sleep(p.measure_s)
            while True:
                host_t1, dev_t1 = self._now(), self.poller.device_now_us()
                point = reduce_point(self.poller.streams, dev_t0, dev_t1, self.calibration, self.engine_map,
                                     index=len(self.points))
                sem = point["efficiency_sem"]
                remaining_s = p.max_measure_s - (host_t1 - host_t0)
                if not (sem > p.target_efficiency_sem) or remaining_s < 0.05:
                    break  # (a NaN sem cannot improve by waiting; a sliver of time cannot either)
                await self._sleep(min(1.0, remaining_s))
            if not point["torque_secondary_nm"] >= p.min_point_torque_nm:
                self._log("skip", reason=f"torque {point['torque_secondary_nm']:.2f} N m below "
                                         f"{p.min_point_torque_nm} N m: brake not yet loading")
                self._adapt_step(math.nan, math.nan)
                continue
            point.update(settled_by=settled_by, settle_s=settle_s, host_t_start_s=host_t0, host_t_end_s=host_t1,
                         step_s=self._step_s)
            for hook in self.point_hooks:
                hook(point, host_t0, host_t1)
            self.points.append(point)
            self._log("point", **point)
            for fn in self.listeners:
                fn(self)
            rs = point["rpm_secondary"]
            self._adapt_step(last_rs, rs)
            last_rs = rs
            if not math.isnan(rs) and rs < p.min_secondary_rpm:
                self._enter(State.DONE, f"secondary below {p.min_secondary_rpm:.0f} rpm")
                return
            if len(self.points) >= p.max_points:
                self._enter(State.DONE, f"{p.max_points} points")
                return

    def _adapt_step(self, rs_before: float, rs_after: float) -> None:
        """Aim at ~target_points over the range: lengthen short steps, shorten long ones."""
        p = self.plan
        if math.isnan(rs_before) or math.isnan(rs_after):
            return
        want = p.expected_secondary_span_rpm / p.target_points
        got = rs_before - rs_after
        if got < 0.5 * want:
            self._step_s = min(p.step_max_s, self._step_s * 1.5)
        elif got > 1.5 * want:
            self._step_s = max(p.step_min_s, self._step_s * 0.6)

    async def _settle(self) -> tuple[str, float]:
        p, c = self.plan, self.plan.settle
        t0 = self._now()
        if p.settle_mode == "fixed":
            await self._sleep(c.fixed_settle_s)
            return "fixed", c.fixed_settle_s
        await self._sleep(c.min_settle_s)
        while True:
            now_dev = self.poller.device_now_us()
            if now_dev is not None and self._now() - t0 >= c.window_s:
                ok, _ = is_settled(self.poller.streams, now_dev, self.calibration.slope_counts_per_nm,
                                   self.calibration.intercept_counts, c)
                if ok:
                    return "detected", self._now() - t0
            if self._now() - t0 >= c.max_settle_s:
                return "timeout", self._now() - t0
            if self.poller.rpm(v1.CH_SECONDARY) < p.min_secondary_rpm and self._now() - t0 > c.min_settle_s + 1:
                return "below_min", self._now() - t0
            await self._sleep(0.1)

    # --- safety ----------------------------------------------------------------------------------
    async def _safety_loop(self) -> None:
        lim = self.limits
        while True:
            await asyncio.sleep(lim.check_period_s)
            self.act.tick(self._now())
            trip = self.check_limits()
            if trip:
                self.abort(*trip)
                return

    def check_limits(self) -> tuple[str, str, float] | None:
        """(cause, detail, trigger time) of the first limit exceeded, or None."""
        lim = self.limits
        now = self._now()
        poller = self.poller
        last = poller.last_valid_frame_s if poller.last_valid_frame_s is not None else poller.started_s
        if last is not None and now - last > lim.comms_timeout_s:
            return ("comms_lost", f"no valid frame for {now - last:.3f} s (limit {lim.comms_timeout_s} s)",
                    last + lim.comms_timeout_s)
        if poller.thermometer is not None and poller.started_s is not None:
            seen = poller.rotor_temp_time_s if not math.isnan(poller.rotor_temp_time_s) else poller.started_s
            if now - seen > lim.thermometer_timeout_s:
                return ("thermometer_lost", f"no rotor temperature for {now - seen:.2f} s",
                        seen + lim.thermometer_timeout_s)
        temp = poller.rotor_temp_c
        if not math.isnan(temp) and temp > lim.rotor_temp_max_c:
            return ("over_temperature", f"rotor {temp:.1f} C > {lim.rotor_temp_max_c:.0f} C",
                    poller.rotor_temp_time_s)
        rp, rs = poller.rpm(v1.CH_PRIMARY), poller.rpm(v1.CH_SECONDARY)
        if self.state in _LOADED_STATES:
            # One Hall sensor silent while the other shows the drivetrain turning
            # means a dead sensor: without it over-speed cannot be seen. The
            # secondary may legitimately stall under a heavy brake (clutch slips),
            # so it only counts at full throttle with the engine well above engagement.
            if rp == 0.0 and rs > lim.sensor_check_rpm:
                return "sensor_fault", f"primary Hall silent while the secondary turns at {rs:.0f} rpm", now
            if rs == 0.0 and rp > lim.overspeed_primary_rpm * 0.75 and self.state is State.WARMUP:
                return "sensor_fault", f"secondary Hall silent at full throttle (primary {rp:.0f} rpm)", now
        if rp > lim.overspeed_primary_rpm:
            return "overspeed", f"primary {rp:.0f} rpm > {lim.overspeed_primary_rpm:.0f}", now
        if rs > lim.overspeed_secondary_rpm:
            return "overspeed", f"secondary {rs:.0f} rpm > {lim.overspeed_secondary_rpm:.0f}", now
        return None
