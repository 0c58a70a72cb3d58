"""The shipped test plans, by name.

``thesis-step``: the thesis's open-loop test — step the brake, wait for steady state,
average (the default).  ``speed-hold``: closed-loop secondary-speed setpoints down the
range (:mod:`dyno.control.speed_hold`), each point measured until its 95 % confidence
interval on efficiency is ±1 pp (or a 10 s cap).
"""

from __future__ import annotations

from dataclasses import replace

from dyno.control.controller import TestPlan

PLANS = {
    "thesis-step": TestPlan(),
    "speed-hold": TestPlan(mode="speed-hold", target_efficiency_ci95=0.01, measure_s=2.0, max_measure_s=10.0),
    "engagement": TestPlan(mode="engagement"),  # dyno.control.characterise
    "coast-down": TestPlan(mode="coast-down"),  # dyno.control.coastdown
}


def plan_named(name: str, **overrides) -> TestPlan:
    from dyno.errors import ConfigError

    if name not in PLANS:
        raise ConfigError("command line", "--plan", f"one of {', '.join(PLANS)}, got {name!r}")
    return replace(PLANS[name], **overrides)
