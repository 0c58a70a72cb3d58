"""The test plans, by name, and the runner of each plan mode.

A plan is a :class:`~dyno.control.api.TestPlan`; the shipped ones are TOML files in
``dyno/control/plan_files/`` (:mod:`dyno.control.planfile` reads them), so a user's own plan
file is the same thing as a shipped one.  ``--plan`` takes a shipped name, a name registered
in ``dyno.control.registry.PLANS`` by code, or a path (a value ending in ``.toml`` or containing ``/``).

A plan's ``mode`` names its runner, a coroutine ``runner(ctx)`` handed the plan context
(:class:`dyno.control.api.PlanContext`) and registered in ``dyno.control.registry.RUNNERS`` as ``"module:function"``
(imported when used); this package holds the shipped runners (``step``: :mod:`.thesis_step`).  To add a
mode: add its runner and its parameters to :mod:`dyno.control.registry` (and, if it needs no file, a
:class:`TestPlan` to its ``PLANS``); a plan file can then use it by name (docs/plans.md).
"""

from __future__ import annotations

from dataclasses import replace

from dyno.control.api import TestPlan
from dyno.control.planfile import load_plan_file, shipped_plans
# The mode table lives in dyno.control.registry (the plan-file reader needs it too, and this module
# needs the reader: one way, registry <- planfile <- plans).
from dyno.control.registry import PLANS
from dyno.errors import ConfigError

__all__ = ["default_plan_name", "is_plan_path", "plan_named", "plan_names"]


def plan_names() -> list[str]:
    """Shipped plan files and code plans, by name."""
    return sorted(set(shipped_plans()) | set(PLANS))


def is_plan_path(value: str) -> bool:
    return value.endswith(".toml") or "/" in value


def plan_named(name: str, **overrides) -> TestPlan:
    """The plan ``name`` (shipped file, code plan, or a path to a plan file) with ``overrides``."""
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
