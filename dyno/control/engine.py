"""The engine's side of the plan context: :class:`dyno.control.api.PlanContext` over the controller.

A plan runner is handed an :class:`EngineContext` and nothing else: what it may do is listed in the
protocol, and every call lands here, in the engine, which alone touches the controller's insides (its
state table, its gate on the outputs, its measuring windows, its log).  A closed loop a plan needs is
the engine's hold service (:mod:`dyno.control.holds`); the controller ends it with the run, after which
its last word (the latched safe state) stands.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from dyno.control.api import Hold, HoldResult, PlanConfig, State, TestPlan
from dyno.control.holds import HoldService
from dyno.control.readings import Readings
from dyno.rig.inertia import InertiaConfig


class EngineContext:
    """The plan context of one run (see :class:`dyno.control.api.PlanContext` for each member)."""

    def __init__(self, engine) -> None:
        self._engine = engine
        self.read = Readings(engine.poller, lambda: self.config)
        self._holds = HoldService(_HoldPrimitives(self))
        self._steps: set[asyncio.Task] = set()  # a bounded step under way (the engine's task, not the plan's)

    # --- what the plan reads ---------------------------------------------------------------------
    @property
    def plan(self) -> TestPlan:
        return self._engine.plan

    @property
    def config(self) -> PlanConfig:
        e = self._engine
        return PlanConfig(limits=e.limits, calibration=e.calibration, engine_map=e.engine_map, control=e.control,
                          inertia=e.inertia or InertiaConfig(), shift_prediction=e.shift_prediction)

    @property
    def state(self) -> State:
        return self._engine.state

    # --- time ------------------------------------------------------------------------------------
    def now(self) -> float:
        return self._engine.rig_now()

    async def sleep(self, dt_s: float) -> None:
        await self._engine.rig_sleep(dt_s)

    async def checkpoint(self) -> None:
        await self._engine.wait_resumed()

    # --- outputs (the engine's gate) -------------------------------------------------------------
    def brake(self, direction: int) -> None:
        self._holds.cancel()  # a direct command ends a hold under way
        self._engine.brake(direction)

    def throttle(self, fraction: float, *, log: bool = True) -> None:
        self._engine.set_throttle(fraction, log=log)

    def cut_engine(self) -> None:
        self._engine.cut_engine()

    async def hold(self, request: Hold) -> HoldResult:
        return await self._holds.hold(request)

    async def bounded(self, step, limit) -> str | None:
        task = asyncio.create_task(step, name="plan-step")
        self._steps.add(task)
        why = None
        try:
            while not task.done():
                await asyncio.wait({task}, timeout=0.05)
                why = None if task.done() else limit()
                if why:
                    break
            if not why:
                task.result()
        finally:
            if not task.done():
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
            self._steps.discard(task)
        return why

    # --- the state table, the log, the points ----------------------------------------------------
    def phase(self, state: State, reason: str = "") -> None:
        self._engine._enter(state, reason)

    def log(self, doc_type: str, **fields) -> None:
        self._engine._log(doc_type, **fields)

    async def measure(self, give_up=None, plan: TestPlan | None = None, since_s: float = 0.0,
                      fixed_s: float | None = None) -> tuple:
        e = self._engine
        saved = e.plan
        if plan is not None:
            e.plan = plan  # the window's own targets, for this window only
        try:
            if fixed_s is not None:
                self._holds.raise_if_failed()
                return await e._measure(since_s=0.0, fixed_s=fixed_s)
            async with self._holds.frozen():
                result = await e._measure(give_up=give_up, since_s=since_s)
            self._holds.raise_if_failed()
            return result
        finally:
            e.plan = saved

    def record(self, point: dict, host_t0: float, host_t1: float) -> None:
        self._engine._record_point(point, host_t0, host_t1)

    async def loaded(self, *, wait_warm_up: bool = False) -> None:
        e = self._engine
        if e.load_since_s is None:
            e.load_since_s = e.rig_now()
        if wait_warm_up:
            await e._warm_up_at_load()

    def set_results(self, results: dict, *, truths: bool = True, log: bool = True) -> None:
        e = self._engine
        results.setdefault("test_time_s", e.rig_now() - e.go_rig_s if e.go_rig_s is not None else None)
        if log:
            e._set_results(results, hooks=truths)
            return
        if truths:
            for hook in e.result_hooks:
                hook(results)
        e.results = results

    # --- failure, files --------------------------------------------------------------------------
    def fail(self, cause: str, detail: str) -> None:
        self._engine.abort(cause, detail)

    def write_artifact(self, name: str, doc: dict) -> None:
        run_dir = getattr(self._engine.writer, "run_dir", None)
        if run_dir is None:
            return
        try:
            Path(run_dir, name).write_text(json.dumps(doc, indent=1, allow_nan=False))
        except (OSError, ValueError) as exc:
            self.log("warning", detail=f"{name} not written: {exc}")

    # --- the engine's own (not the plan's) -------------------------------------------------------
    async def end_holds(self) -> None:
        """The end of the run: a bounded step or a hold still running is stopped (the engine's, not the plan's)."""
        left = [t for t in self._steps if not t.done()]
        for t in left:
            t.cancel()
        if left:
            await asyncio.gather(*left, return_exceptions=True)
        await self._holds.stop()


class _HoldPrimitives:
    """What the hold service drives, over one run's context: the gated brake without ending the hold."""

    def __init__(self, ctx: EngineContext) -> None:
        self._ctx = ctx
        self.read = ctx.read
        self.now, self.sleep, self.checkpoint = ctx.now, ctx.sleep, ctx.checkpoint

    def actuate(self, direction: int) -> None:
        self._ctx._engine.brake(direction)

    def control(self):
        return self._ctx._engine.control
