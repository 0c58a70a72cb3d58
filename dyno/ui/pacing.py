"""Pacing a simulated rig on the UI's real-time loop: the plan's durations and the actuators' clock.

The UI runs the physics at ``speed`` x real time on a scaled clock (``dyno.ui.session``): the plan's
durations shrink by the same factor, and the simulated driver's release timer reads the physics' time.
"""

from __future__ import annotations

from dataclasses import replace

from dyno.control.api import TestPlan


def scaled_plan(plan: TestPlan, speed: float) -> TestPlan:
    """The plan with every duration divided by ``speed`` (host seconds for ``speed`` x simulated ones)."""
    if speed == 1.0:
        return plan
    k = 1.0 / speed
    settle = replace(plan.settle, min_settle_s=plan.settle.min_settle_s * k,
                     max_settle_s=plan.settle.max_settle_s * k, fixed_settle_s=plan.settle.fixed_settle_s * k)
    return replace(plan, engine_detect_s=plan.engine_detect_s * k, engine_start_timeout_s=plan.engine_start_timeout_s * k,
                   warmup_s=plan.warmup_s * k,
                   step_s=plan.step_s * k, step_min_s=plan.step_min_s * k, step_max_s=plan.step_max_s * k,
                   measure_s=plan.measure_s * k, max_measure_s=plan.max_measure_s * k, settle_mode="fixed",
                   settle=settle)


class SimTimeActuators:
    """The simulated actuators with ``tick`` translated to simulated time.

    The controller ticks with the loop's time; the simulated release stroke is
    timed in the physics' time.  Everything else passes through.
    """

    def __init__(self, inner, sim_now) -> None:
        self._inner = inner
        self._sim_now = sim_now

    def tick(self, now_s: float) -> None:
        self._inner.tick(self._sim_now())

    def __getattr__(self, name):
        return getattr(self._inner, name)
