"""The controller's measurement: a steady window to a point, the warm-up criterion, settling.

A mixin of :class:`dyno.control.controller.TestController` (split from it along this seam: the
state machine and safety there, how a window becomes a recorded point here; the states come from
:mod:`dyno.control.api`, so this base class does not import the controller built on it).  Every
plan runner measures through :meth:`Measuring._measure` and records through :meth:`Measuring._record_point`.
"""

from __future__ import annotations

import math

from dyno.analysis.points import reduce_point
from dyno.analysis.stopping import stop_uncertainty
from dyno.control.api import State
from dyno.protocol import v1

MAX_REMEASURE = 3  # a disturbed measurement window is measured again at most this often


class Measuring:
    """Measurement methods of the TestController (they use its poller, plan, clock and log)."""
    async def _measure(self, give_up=None, since_s: float = 0.0,
                       fixed_s: float | None = None) -> tuple[dict, float, float]:
        """MEASURE: average until the efficiency's uncertainty target or the time cap; a window that a
        disturbance touched is discarded and measured again (at most MAX_REMEASURE times).  ``give_up``
        (a callable, checked each second) ends a window that cannot become a point early: the point
        comes back with ``gave_up`` set (a closed-loop plan's drifting speed).  ``since_s``: the window
        already began this many rig seconds ago (a plan that saw the rig steady and untouched over that
        span: the data are in the streams); not before the warm-up's end, not on a re-measure.
        ``fixed_s``: a window of exactly that length, no stopping rule (a ramp's).

        Returns the reduced point and the window's host start and end times.
        """
        p = self.plan
        rig_before = self.rig_now()
        await self._warm_up_at_load()
        if self.rig_now() > rig_before or not since_s > 0:
            since_s = 0.0  # (the warm-up was waited out: data from before its end are not a point's)
        for attempt in range(MAX_REMEASURE + 1):
            self._enter(State.MEASURE, f"measuring {p.measure_s:.0f}-{p.max_measure_s:.0f} s" if fixed_s is None
                        else f"measuring {fixed_s:g} s")
            # the window's length is the plan's, in rig seconds (self.clock); its ends are kept in host time
            host_t0, rig_t0, dev_t0 = self._now(), self.rig_now(), self.poller.device_now_us()
            if since_s > 0 and dev_t0 is not None:
                host_t0 -= since_s * self.time_scale
                rig_t0 -= since_s
                dev_t0 -= int(since_s * 1e6)
            await self.rig_sleep(max(0.0, rig_t0 + (p.measure_s if fixed_s is None else fixed_s) - self.rig_now()))
            since_s = 0.0
            while True:
                host_t1, rig_t1, dev_t1 = self._now(), self.rig_now(), self.poller.device_now_us()
                point = reduce_point(self.poller.streams, dev_t0, dev_t1, self.calibration, self.engine_map,
                                     index=len(self.points), throttle_frac=self.throttle_frac)
                if fixed_s is not None:
                    break
                # Against the error's upper bound, not the estimate: few batches must not stop a window
                # on a luckily small estimate (dyno/analysis/stopping.py).
                ci = p.target_efficiency_ci95 is not None
                bound = stop_uncertainty(point, ci95=ci, quantile=p.stop_quantile)
                unsure = bound > (p.target_efficiency_ci95 if ci else p.target_efficiency_sem)
                remaining_s = p.max_measure_s - (rig_t1 - rig_t0)
                if unsure and give_up is not None and give_up():
                    point["gave_up"] = True
                    break
                if not unsure or remaining_s < 0.05:
                    break  # (a NaN sem cannot improve by waiting; a sliver of time cannot either)
                await self.rig_sleep(min(p.measure_check_s, remaining_s))
            # Let the poller look once more: a loss or reset at the window's end is reported late.
            await self._sleep(2.0 * getattr(self.poller, "poll_period_s", 0.0))
            disturbed = self.poller.disturbances_between(host_t0, self._now())
            if not await self._sensors_alive():
                disturbed.append({"detail": "a Hall channel went silent at the window's end"})
            if not disturbed:
                break
            why = "; ".join(d["detail"] for d in disturbed)
            entry = {"index": len(self.points), "host_t_start_s": host_t0, "host_t_end_s": host_t1,
                     "reason": why, "attempt": attempt + 1}
            self.discards.append(entry)
            self._log("discard", **entry)
            for fn in self.listeners:
                fn(self)
            if attempt == MAX_REMEASURE:
                point["valid"] = False
                point.setdefault("faults", []).append({"reason": f"window disturbed: {why}"})
        return point, host_t0, host_t1

    def _set_results(self, results: dict, *, hooks: bool = True) -> None:
        for hook in self.result_hooks if hooks else ():
            hook(results)
        self.results = results
        self._log("characterisation", **results)

    async def _warm_up_at_load(self) -> None:
        """Before the first point: the plan's time at load (``warmup_at_load_s``), waited out if short."""
        need = self.plan.warmup_at_load_s
        if self.warmup is not None or need <= 0:
            return
        if self.load_since_s is None:
            self.load_since_s = self.rig_now()
        left = need - (self.rig_now() - self.load_since_s)
        if left > 0:
            self._log("warmup_wait", wait_s=left)
            await self.rig_sleep(left)
        self.warmup = {"criterion": "time at load", "required_s": need,
                       "at_load_s": self.rig_now() - self.load_since_s}
        self._log("warmup", **self.warmup)

    def _record_point(self, point: dict, host_t0: float, host_t1: float) -> None:
        point.update(host_t_start_s=host_t0, host_t_end_s=host_t1)
        for hook in self.point_hooks:
            hook(point, host_t0, host_t1)
        self.points.append(point)
        self._log("point", **point)
        for fn in self.listeners:
            fn(self)

    def _channel_quiet_s(self, channel: int) -> float:
        e = self.poller.streams.edges[channel]
        now = self.poller.device_now_us()
        return math.inf if not e or now is None else (now - e[-1]) * 1e-6

    async def _sensors_alive(self) -> bool:
        """Both Hall channels still ticking; if not, give the safety monitor time to judge.

        A shaft cannot stop between two edges at test speeds, so a silent channel is
        a dead sensor (the monitor aborts) or a stall (it aborts too); either way the
        window is not averaged into a point.
        """
        lim = self.limits
        for ch in (v1.CH_PRIMARY, v1.CH_SECONDARY):
            if self._channel_quiet_s(ch) > 0.1:
                await self.rig_sleep(max(lim.primary_quiet_s, lim.secondary_quiet_s) + 0.05)  # (judged in device time)
                return False
        return True
