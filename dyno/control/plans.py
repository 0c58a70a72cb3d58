"""The test plans, by name, and the runner of each plan mode.

A plan is a :class:`~dyno.control.controller.TestPlan`; the shipped ones are TOML files in
``dyno/control/plan_files/`` (:mod:`dyno.control.planfile` reads them), so a user's own plan
file is the same thing as a shipped one.  ``--plan`` takes a shipped name, a name registered
in :data:`PLANS` by code, or a path (a value ending in ``.toml`` or containing ``/``).

A plan's ``mode`` names its runner: ``step`` is the controller's own open-loop loop, every
other mode is a coroutine ``runner(controller)`` registered in :data:`RUNNERS` as
``"module:function"`` (imported when used).  To add a mode: add its runner here (and, if it
needs no file, a :class:`TestPlan` to :data:`PLANS`); a plan file can then use it by name.
"""

from __future__ import annotations

import importlib
from dataclasses import replace

from dyno.control.controller import TestPlan

#: mode -> "module:coroutine" (or the coroutine function itself); it takes the controller after the warm-up
#: (those in FROM_IDLE right after GO)
RUNNERS: dict[str, object] = {
    "speed-hold": "dyno.control.speed_hold:run_speed_hold",
    "steps": "dyno.control.steps:run_steps",
    "engagement": "dyno.control.characterise:run_engagement",
    "coast-down": "dyno.control.coastdown:run_coast_down",
    "drive-grid": "dyno.control.drive_grid:run_drive_grid",
}

#: modes whose runner starts from idle (GO, then no full-throttle warm-up): the characterisations
FROM_IDLE = {"engagement", "coast-down"}

#: plans registered in code (no file); the shipped plan files are added to these by name
PLANS: dict[str, TestPlan] = {
    "engagement": TestPlan(mode="engagement", name="engagement"),  # dyno.control.characterise
    "coast-down": TestPlan(mode="coast-down", name="coast-down"),  # dyno.control.coastdown
}


def runner_for(mode: str):
    """The coroutine function that runs a plan of ``mode`` (see :data:`RUNNERS`)."""
    from dyno.errors import ConfigError

    if mode not in RUNNERS:
        raise ConfigError("plan", "mode", f"one of step, {', '.join(sorted(RUNNERS))}, got {mode!r}")
    if callable(RUNNERS[mode]):
        return RUNNERS[mode]
    module, _, fn = RUNNERS[mode].partition(":")
    return getattr(importlib.import_module(module), fn)


def known_modes() -> set[str]:
    """Every mode a plan file may name: ``step``, the registered runners, and any mode a code plan uses."""
    return {"step", *RUNNERS, *(p.mode for p in PLANS.values())}


def plan_names() -> list[str]:
    """Shipped plan files and code plans, by name."""
    from dyno.control.planfile import shipped_plans

    return sorted(set(shipped_plans()) | set(PLANS))


def is_plan_path(value: str) -> bool:
    return value.endswith(".toml") or "/" in value


def plan_named(name: str, **overrides) -> TestPlan:
    """The plan ``name`` (shipped file, code plan, or a path to a plan file) with ``overrides``."""
    from dyno.control.planfile import load_plan_file, shipped_plans
    from dyno.errors import ConfigError

    if is_plan_path(name):
        plan = load_plan_file(name)
    elif name in shipped_plans():
        plan = load_plan_file(shipped_plans()[name])
    elif name in PLANS:
        plan = replace(PLANS[name], name=PLANS[name].name or name)
    else:
        raise ConfigError("command line", "--plan", f"one of {', '.join(plan_names())} or a plan file "
                          f"(a path ending in .toml), got {name!r}")
    return replace(plan, **overrides)


def default_plan_name() -> str:
    return "speed-hold"
