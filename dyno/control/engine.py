"""The engine's side of the plan context: :class:`dyno.control.api.PlanContext` over the controller.

A plan runner is handed an :class:`EngineContext` and nothing else: what it may do is listed in the
protocol, and every call lands here, in the engine, which alone touches the controller's insides (its
state table, its gate on the outputs, its measuring windows, its log).  Tasks a plan needs beside it
(a closed-loop hold) are the engine's: :meth:`EngineContext.hold_task` keeps them and the controller
cancels what is left when the run ends, after which its last word (the latched safe state) stands.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from dyno.control.api import PlanConfig, State, TestPlan

#: controller attributes a plan may read, by the PlanConfig field that carries them
_CONFIG_FIELDS = tuple(PlanConfig.__dataclass_fields__)


class EngineContext:
    """The plan context of one run (see :class:`dyno.control.api.PlanContext` for each member)."""

    def __init__(self, engine) -> None:
        self._engine = engine
        self.tasks: set[asyncio.Task] = set()

    # --- what the plan reads ---------------------------------------------------------------------
    @property
    def plan(self) -> TestPlan:
        return self._engine.plan

    @property
    def config(self) -> PlanConfig:
        e = self._engine
        return PlanConfig(**{name: getattr(e, name, None) for name in _CONFIG_FIELDS})

    @property
    def state(self) -> State:
        return self._engine.state

    @property
    def points(self) -> tuple:
        return tuple(self._engine.points)

    @property
    def throttle_frac(self) -> float:
        return self._engine.throttle_frac

    @property
    def streams(self):
        return self._engine.poller.streams

    def rpm(self, channel: int) -> float:
        return self._engine.poller.rpm(channel)

    def device_now_us(self):
        return self._engine.poller.device_now_us()

    # --- time ------------------------------------------------------------------------------------
    def now(self) -> float:
        return self._engine.rig_now()

    def host_now(self) -> float:
        return self._engine._now()

    def test_time_s(self) -> float:
        e = self._engine
        return e.rig_now() - e.go_rig_s

    async def sleep(self, dt_s: float) -> None:
        await self._engine.rig_sleep(dt_s)

    async def checkpoint(self) -> None:
        await self._engine._resume.wait()

    # --- outputs (the engine's gate) -------------------------------------------------------------
    def brake(self, direction: int) -> None:
        self._engine.brake(direction)

    def throttle(self, fraction: float, *, log: bool = True) -> None:
        self._engine.set_throttle(fraction, log=log)

    def cut_engine(self) -> None:
        self._engine.cut_engine()

    # --- the state table, the log, the points ----------------------------------------------------
    def phase(self, state: State, reason: str = "") -> None:
        self._engine._enter(state, reason)

    def log(self, doc_type: str, **fields) -> None:
        self._engine._log(doc_type, **fields)

    async def measure(self, give_up=None, plan: TestPlan | None = None, since_s: float = 0.0) -> tuple:
        e = self._engine
        if plan is None:
            return await e._measure(give_up=give_up, since_s=since_s)
        saved, e.plan = e.plan, plan  # the window's own targets, for this window only
        try:
            return await e._measure(give_up=give_up, since_s=since_s)
        finally:
            e.plan = saved

    def record(self, point: dict, host_t0: float, host_t1: float) -> None:
        self._engine._record_point(point, host_t0, host_t1)

    async def warm_up_at_load(self) -> None:
        await self._engine._warm_up_at_load()

    def mark_loaded(self) -> None:
        e = self._engine
        if e.load_since_s is None:
            e.load_since_s = e.rig_now()

    def set_results(self, results: dict, *, hooks: bool = True, log: bool = True) -> None:
        if log:
            self._engine._set_results(results, hooks=hooks)
            return
        if hooks:
            self.add_truths(results)
        self._engine.results = results

    def add_truths(self, results: dict) -> None:
        for hook in self._engine.result_hooks:
            hook(results)

    def tune_control(self, control, identified: dict) -> None:
        e = self._engine
        if control is not None:
            e.control = control
        e.identified = identified

    # --- tasks, failure, files -------------------------------------------------------------------
    def hold_task(self, coro, name: str) -> asyncio.Task:
        task = asyncio.create_task(coro, name=name)
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)
        return task

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

    async def cancel_tasks(self) -> None:
        """The end of the run: the plan's tasks still running are cancelled (the engine's, not the plan's)."""
        left = [t for t in self.tasks if not t.done()]
        for t in left:
            t.cancel()
        if left:
            await asyncio.gather(*left, return_exceptions=True)
