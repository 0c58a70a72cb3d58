"""The engine's hold service: one closed loop on the brake for a speed, the engine or the torque.

A plan asks for a hold (``await ctx.hold(SpeedHold(rpm=…))``, :class:`dyno.control.api.Hold`) and gets a
:class:`~dyno.control.api.HoldResult`; the loop itself is the engine's task (a plan starts none).  Each
period ``T`` it reads the held variable over the gains' window, turns the relative error into an
actuator command by the law (:class:`dyno.control.hold_law.HoldLaw`) and gives at most one pulse::

    e = s (x - x_set) / x_set,   s = +1 (more brake lowers x: speeds), -1 (torque, or ``load_raises``)

A new request of the same variable, sign and gains retargets the running loop (a setpoint change owes
the feed-forward travel the gains' ``ff_s`` says); any other starts a new loop with a fresh law.  A
measurement freezes the loop for its window, after letting a pulse under way end (its travel is not
the window's).  A direct brake command, the next plan, or the end of the run stops the loop and the
actuator.
"""

from __future__ import annotations

import asyncio
import math
from contextlib import asynccontextmanager

from dyno.control.api import Hold, HoldResult
from dyno.control.hold_law import HoldGains, HoldLaw
from dyno.control.outputs import STOP

#: the sign of each variable's error: + where more brake lowers it
SIGN = {"secondary": 1.0, "engine": 1.0, "torque": -1.0}


def gains_for(control, variable: str) -> HoldGains:
    """The law's gains for ``variable`` from rig.toml's ``[control]`` (None: that table's defaults)."""
    from dyno.rig.config import ControlConfig

    return HoldGains.from_config(control if control is not None else ControlConfig(), variable)


class HoldService:
    """The hold loop of one run (module doc).  ``engine``: the primitives it drives — ``read``
    (:class:`~dyno.control.readings.Readings`), ``now()``, ``await sleep(s)``, ``await checkpoint()``,
    ``actuate(direction)`` (the gated brake, without ending the hold) and ``control()`` ([control])."""

    def __init__(self, engine) -> None:
        self._e = engine
        self._task: asyncio.Task | None = None
        self._key: tuple | None = None
        self._law: HoldLaw | None = None
        self._variable = "secondary"
        self._sign = 1.0
        self._setpoint = math.nan  # what the loop holds now (moves towards _target at _rate)
        self._target = math.nan
        self._rate = 0.0
        self._frozen = False
        self._pulsing = False
        self._last_pulse_end_s = -math.inf
        self._last_value = math.nan

    @property
    def active(self) -> bool:
        return self._task is not None and not self._task.done()

    async def hold(self, req: Hold) -> HoldResult:
        """Start or retarget the loop for ``req``, then (``req.wait``) wait until it is reached or given up."""
        if req.variable not in SIGN:
            raise ValueError(f"hold: variable one of {', '.join(SIGN)}, got {req.variable!r}")
        gains = req.gains or gains_for(self._e.control(), req.variable)
        sign = -1.0 if req.variable == "torque" or req.load_raises else 1.0  # (more brake always raises torque)
        key = (req.variable, sign, gains)
        if key != self._key or not self.active:
            await self.stop()
            self._key, self._variable, self._sign = key, req.variable, sign
            self._law = HoldLaw(gains)
            self._setpoint = self._target = req.setpoint
            self._task = asyncio.create_task(self._loop(), name=f"hold-{req.variable}")
        else:
            if req.rate_per_s <= 0 and req.setpoint != self._setpoint:
                self._law.feed_forward(self._setpoint, req.setpoint, -sign)
                self._setpoint = req.setpoint
            self._target = req.setpoint
        self._rate = req.rate_per_s if req.rate_per_s > 0 else 0.0
        if not req.wait:
            return HoldResult(False, self._last_value, 0.0, self._quiet_s())
        return await self._settle(req, gains)

    async def _settle(self, req: Hold, gains: HoldGains) -> HoldResult:
        t0 = self._e.now()
        since = None
        while True:
            await self._e.sleep(0.05)
            self.raise_if_failed()
            x = self._e.read.value(req.variable, gains.speed_window_s)
            if abs(x - req.setpoint) <= req.tolerance_rel * req.setpoint:
                since = since if since is not None else self._e.now()
                if self._e.now() - since >= req.in_band_s and self._steady(req):
                    return HoldResult(True, x, self._e.now() - t0, self._quiet_s())
            else:
                since = None
            if self._e.now() - t0 > req.max_approach_s:
                return HoldResult(False, x, self._e.now() - t0, self._quiet_s())

    def _steady(self, req: Hold) -> bool:
        if not req.settle_rate_rel_per_s > 0:
            return True
        rate = self._e.read.rate_rel_per_s(req.setpoint, req.settle_rate_window_s)
        return abs(rate) <= req.settle_rate_rel_per_s

    def _quiet_s(self) -> float:
        return self._e.now() - self._last_pulse_end_s

    def raise_if_failed(self) -> None:
        """Re-raise the loop's own failure (a hold that died must not pass for one holding)."""
        if self._task is not None and self._task.done() and not self._task.cancelled():
            self._task.result()

    @asynccontextmanager
    async def frozen(self):
        """The brake left where the loop put it (a pulse under way ends first), for a measurement."""
        self._frozen = True
        try:
            while self._pulsing and self.active:
                await self._e.sleep(0.005)
            yield
        finally:
            self._frozen = False

    async def stop(self) -> None:
        """End the loop (the actuator stopped)."""
        task, self._task, self._key = self._task, None, None
        if task is not None and not task.done():
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            self._e.actuate(STOP)
        self._pulsing = False

    def cancel(self) -> None:
        """End the loop without waiting (a direct brake command follows at once)."""
        task, self._task, self._key = self._task, None, None
        if task is not None and not task.done():
            task.cancel()
        self._pulsing = False

    async def _loop(self) -> None:
        law = self._law
        g = law.g
        while True:
            await self._e.checkpoint()
            if self._rate > 0 and self._setpoint != self._target:
                step = self._rate * g.period_s
                d = self._target - self._setpoint
                self._setpoint = self._target if abs(d) <= step else self._setpoint + math.copysign(step, d)
            if self._frozen:
                await self._e.sleep(g.period_s)
                continue
            x = self._e.read.value(self._variable, g.speed_window_s)
            self._last_value = x
            e = self._error(x, self._setpoint)
            u = law.command(e, g.period_s)
            direction, on_s = law.pulse(u, e)
            if direction == STOP:
                await self._e.sleep(g.period_s)
                continue
            self._e.actuate(direction)
            self._pulsing = True
            try:
                await self._e.sleep(on_s)
            finally:
                if self._task is asyncio.current_task():  # (ended by a plan's brake command: that one stands)
                    self._e.actuate(STOP)
                self._pulsing, self._last_pulse_end_s = False, self._e.now()
            await self._e.sleep(max(0.0, g.period_s - on_s))

    def _error(self, x: float, sp: float) -> float:
        if not (sp > 0) or not math.isfinite(x) or (self._variable != "torque" and not x > 0):
            return math.nan
        return self._sign * (x - sp) / sp

    @property
    def law(self) -> HoldLaw | None:
        """The running loop's law (its state: the travel owed, the integral), None before the first hold."""
        return self._law
