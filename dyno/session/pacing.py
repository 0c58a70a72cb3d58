"""Pacing a simulated rig on a real-time loop (the live session, ``dyno ui --speed N``): its scaled clock.

The physics runs at ``speed`` x real time on a scaled clock, ``t_sim = (loop.time() - t0) * speed``,
starting at 0 (the loop's monotonic clock is hours since boot; the physics would otherwise simulate them
all on the first poll).  The composition root (:func:`dyno.session.root.build`) takes the clock and paces the
rest from it: the plan's durations shrink by the same factor (the controller runs on the loop's clock),
the simulated driver's release timer reads the physics' time, the polls drain ``speed`` x more frames.
"""

from __future__ import annotations

from dataclasses import replace

from dyno.control.api import TestPlan


class ScaledClock:
    """Simulated seconds on a real-time loop: ``now() = (loop_time() - t0) * speed``."""

    def __init__(self, loop_time, speed: float = 1.0) -> None:
        self._loop_time = loop_time
        self.speed = float(speed)
        self.t0 = loop_time()

    def now(self) -> float:
        return (self._loop_time() - self.t0) * self.speed

    def host_to_sim(self, t_host_s: float) -> float:
        """A loop time as simulated time (drills' true-time latencies)."""
        return (t_host_s - self.t0) * self.speed

    def restart(self) -> None:
        """Simulated time starts now (a session's rig starts when its first poll does, not when it was built)."""
        self.t0 = self._loop_time()


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
