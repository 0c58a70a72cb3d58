"""The plan modes: which runner runs each mode, and the plans registered in code.

Split from :mod:`dyno.control.plans` so that the dependency runs one way: the plan-file reader
(:mod:`dyno.control.planfile`, which checks a file's ``mode``) and :mod:`dyno.control.plans`
(which finds plans by name, through that reader) both read this table, and it imports neither.
Nor does it import a runner's module or the controller: a runner is named as a
``"module:function"`` string and imported when used (:func:`runner_for`), so this module is a
leaf over :mod:`dyno.control.api`.  ``dyno.control.plans`` re-exports every name here (the same
objects).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from types import MappingProxyType

from dyno.control.api import TestPlan
from dyno.errors import ConfigError

#: mode -> "module:coroutine" (or the coroutine function itself); it takes the plan context
#: (:class:`dyno.control.api.PlanContext`) and its parameters (:func:`params_of`) after the warm-up (those in FROM_IDLE right after GO).
#: Read-only: a run's own extra modes (a test's, a bench's) come with its spec (``dyno.session.root.RunSpec.runners``).
RUNNERS: Mapping[str, object] = MappingProxyType({
    "step": "dyno.control.plans.thesis_step:run_thesis_step",
    "speed-hold": "dyno.control.plans.speed_hold:run_speed_hold",
    "steps": "dyno.control.plans.steps:run_steps",
    "engagement": "dyno.control.plans.characterise:run_engagement",
    "coast-down": "dyno.control.plans.coastdown:run_coast_down",
    "drive-grid": "dyno.control.plans.drive_grid:run_drive_grid",
})

#: modes whose runner starts from idle (GO, then no full-throttle warm-up): the characterisations
FROM_IDLE = {"engagement", "coast-down"}

#: plans registered in code (no file); the shipped plan files are added to these by name
PLANS: dict[str, TestPlan] = {
    "engagement": TestPlan(mode="engagement", name="engagement"),  # dyno.control.plans.characterise
    "coast-down": TestPlan(mode="coast-down", name="coast-down"),  # dyno.control.plans.coastdown
}


#: mode -> "module:dataclass" of its own parameters (a plan file's table named after the mode, e.g.
#: [speed_hold]; mode "steps": its [[step]] list).  Mode "step" has none: its parameters are the plan's
#: [test] fields (:class:`TestPlan`).  A runner is called ``runner(ctx, params)`` with an instance.
PARAMS: Mapping[str, str] = MappingProxyType({
    "speed-hold": "dyno.control.plans.speed_hold:SpeedHoldPlan",
    "steps": "dyno.control.plans.steps:StepsPlan",
    "engagement": "dyno.control.plans.characterise:EngagementPlan",
    "coast-down": "dyno.control.plans.coastdown:CoastDownPlan",
    "drive-grid": "dyno.control.plans.drive_grid:DriveGridPlan",
})


def params_class(mode: str) -> type | None:
    """The dataclass of ``mode``'s parameters (None: the mode has none of its own)."""
    if mode not in PARAMS:
        return None
    module, _, cls = PARAMS[mode].partition(":")
    return getattr(importlib.import_module(module), cls)


def params_of(plan: TestPlan):
    """What ``plan``'s runner is handed: its mode's parameters (the defaults where the plan gives none),
    or, for mode "step", the plan itself."""
    if plan.mode == "step":
        return plan
    cls = params_class(plan.mode)
    if cls is None or isinstance(plan.params, cls):
        return plan.params
    if plan.params is None:
        return cls()
    raise ConfigError("plan", "params", f"a {cls.__name__} for mode {plan.mode!r}, got {type(plan.params).__name__}")


def runner_for(mode: str):
    """The coroutine function that runs a plan of ``mode`` (see :data:`RUNNERS`)."""
    if mode not in RUNNERS:
        raise ConfigError("plan", "mode", f"one of step, {', '.join(sorted(set(RUNNERS) - {'step'}))}, got {mode!r}")
    if callable(RUNNERS[mode]):
        return RUNNERS[mode]
    module, _, fn = RUNNERS[mode].partition(":")
    return getattr(importlib.import_module(module), fn)


def known_modes() -> set[str]:
    """Every mode a plan file may name: ``step``, the registered runners, and any mode a code plan uses."""
    return {"step", *RUNNERS, *(p.mode for p in PLANS.values())}
