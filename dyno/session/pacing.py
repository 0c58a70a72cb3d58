"""Pacing a simulated rig on a real-time loop (the live session, ``dyno ui --speed N``): its scaled clock.

The physics runs at ``speed`` x real time on a scaled clock, ``t_sim = (loop.time() - t0) * speed``,
starting at 0 (the loop's monotonic clock is hours since boot; the physics would otherwise simulate them
all on the first poll).  The composition root (:func:`dyno.session.root.build`) takes the clock and paces the
rest from it: the controller times the plan on it (``now()`` in rig seconds, ``sleep(rig_s)`` waiting
``rig_s / speed`` on the loop), so the plan keeps its own durations; the simulated driver's release timer
reads the physics' time; the polls drain ``speed`` x more frames.  The safety deadlines (heartbeat, link
timeout, watchdog) stay on the loop's clock: they protect the real world, which runs in wall time.
"""

from __future__ import annotations

import asyncio


class ScaledClock:
    """Simulated seconds on a real-time loop: ``now() = (loop_time() - t0) * speed``."""

    def __init__(self, loop_time, speed: float = 1.0, *, held: bool = False) -> None:
        self._loop_time = loop_time
        self.speed = float(speed)
        self.t0 = loop_time()
        # held: the rig's time stands at 0 until :meth:`restart` (what is read while the session is built,
        # the air sensor, is read at rig time 0, and the physics does not run through the building)
        self.held = held

    def now(self) -> float:
        if self.held:
            return 0.0
        return (self._loop_time() - self.t0) * self.speed

    async def sleep(self, rig_s: float) -> None:
        """Wait ``rig_s`` simulated seconds: ``rig_s / speed`` on the loop."""
        await asyncio.sleep(rig_s / self.speed)

    def host_to_sim(self, t_host_s: float) -> float:
        """A loop time as simulated time (drills' true-time latencies)."""
        return (t_host_s - self.t0) * self.speed

    def restart(self) -> None:
        """Simulated time starts now (a session's rig starts when its first poll does, not when it was built)."""
        self.t0 = self._loop_time()
        self.held = False


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
