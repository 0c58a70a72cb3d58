"""What a plan reads of the rig: speeds, torque, ratio and raw windows, over the acquired streams.

A plan observes the rig through :class:`Readings` (``ctx.read``) and never through the streams
themselves, so the streams' layout can change without a plan noticing.  Every reading is over device
time (µs, the streams' time base, :meth:`Readings.device_now_us`); a window is the last ``window_s``
seconds of it.  Speeds are by edge count over the window (one Hall edge per revolution), which is
immune to the firing ripple that scatters single periods::

    n = 60 (k - 1) / (t_k - t_1)        rpm, from the k edges inside the window

Torque is the secondary gauge's mean conversion through the run's (tared) calibration, conversions
with the ADC's error bit left out.  Values are NaN where the window holds nothing to read.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from dyno.acquisition.rpm import rpm_by_count
from dyno.analysis import shift_events
from dyno.control.steady import SettleCriteria, is_settled
from dyno.protocol import v1

#: the variables a hold can hold, and the reading of each
VARIABLES = ("secondary", "engine", "torque")


class Readings:
    """The rig's readings for a plan (module doc).  ``poller``: the acquisition's face (``streams``,
    ``rpm``, ``device_now_us``); ``config``: returns the run's :class:`~dyno.control.api.PlanConfig`
    (read at each call: the calibration is tared at GO)."""

    def __init__(self, poller, config: Callable) -> None:
        self._poller = poller
        self._config = config

    # --- time and live speeds ---------------------------------------------------------------------
    def device_now_us(self) -> int | None:
        """The newest device time seen (µs), None before the first frame."""
        return self._poller.device_now_us()

    def rpm(self, channel: int) -> float:
        """A Hall channel's live speed (``v1.CH_PRIMARY`` / ``v1.CH_SECONDARY``), 0 when it is silent."""
        return self._poller.rpm(channel)

    # --- windowed readings ------------------------------------------------------------------------
    def speed_rpm(self, channel: int, window_s: float) -> float:
        """A Hall channel's speed by edge count over the last ``window_s``."""
        now = self.device_now_us()
        if now is None:
            return math.nan
        rpm, _ = rpm_by_count(self._poller.streams.edge_window(channel, now - int(window_s * 1e6), now))
        return rpm

    def secondary_rpm(self, window_s: float) -> float:
        return self.speed_rpm(v1.CH_SECONDARY, window_s)

    def engine_rpm(self, window_s: float) -> float:
        return self.speed_rpm(v1.CH_PRIMARY, window_s)

    def torque_nm(self, window_s: float) -> float:
        """The secondary (brake) torque, N·m, over the last ``window_s``."""
        now = self.device_now_us()
        if now is None:
            return math.nan
        return self.torque_between_nm(now - int(window_s * 1e6), now)

    def value(self, variable: str, window_s: float) -> float:
        """``variable`` (one of :data:`VARIABLES`: rpm, or N·m for torque) over the last ``window_s``."""
        if variable == "torque":
            return self.torque_nm(window_s)
        return self.speed_rpm(v1.CH_SECONDARY if variable == "secondary" else v1.CH_PRIMARY, window_s)

    def ratio(self, window_s: float = 0.3) -> float:
        """The speed ratio n_primary / n_secondary at the middle of the last ``window_s``."""
        now = self.device_now_us()
        if now is None:
            return math.nan
        t0, mid, half = now - int(window_s * 1e6), now - window_s * 5e5, window_s * 5e5
        rp = shift_events.rpm_at(self.edges(v1.CH_PRIMARY, t0, now), mid, half)
        rs = shift_events.rpm_at(self.edges(v1.CH_SECONDARY, t0, now), mid, half)
        return rp / rs if rs > 0 else math.nan

    def rate_rel_per_s(self, setpoint_rpm: float, window_s: float) -> float:
        """The secondary's rate of change as a fraction of ``setpoint_rpm`` per second: the difference of
        its mean speeds over the last two adjacent ``window_s``, over ``window_s``."""
        now = self.device_now_us()
        if now is None or not setpoint_rpm > 0:
            return math.nan
        w_us = int(window_s * 1e6)
        recent, _ = rpm_by_count(self.edges(v1.CH_SECONDARY, now - w_us, now))
        before, _ = rpm_by_count(self.edges(v1.CH_SECONDARY, now - 2 * w_us, now - w_us))
        return (recent - before) / setpoint_rpm / window_s

    def settled(self, criteria: SettleCriteria) -> bool:
        """The speeds and torque steady by ``criteria`` over their window (:func:`dyno.control.steady.is_settled`)."""
        now = self.device_now_us()
        cal = self._config().calibration
        if now is None or cal is None:
            return False
        ok, _ = is_settled(self._poller.streams, now, cal.slope_counts_per_nm, cal.intercept_counts, criteria)
        return ok

    def channel_quiet_s(self, channel: int) -> float:
        """Seconds of device time since the channel's last edge (inf before its first)."""
        now = self.device_now_us()
        last = self._poller.streams.last_edge_us(channel)
        return math.inf if last is None or now is None else (now - last) * 1e-6

    # --- raw windows, by device time --------------------------------------------------------------
    def edges(self, channel: int, t0_us: int, t1_us: int) -> np.ndarray:
        """The channel's edge times (µs) in [t0_us, t1_us]."""
        return self._poller.streams.edge_window(channel, t0_us, t1_us)

    def torque_between_nm(self, t0_us: int, t1_us: int) -> float:
        """The secondary's mean torque (N·m) over [t0_us, t1_us]."""
        cal = self._config().calibration
        if cal is None:
            return math.nan
        _, codes, status = self._poller.streams.adc_window(int(t0_us), int(t1_us))
        good = codes[(status & v1.ADC_STATUS_ERR) == 0]
        return float(cal.torque_secondary_nm(float(good.mean()))) if good.size else math.nan

    def zero_nm(self, t0_us: int, t1_us: int) -> tuple[float, float]:
        """The torque reading at rest over [t0_us, t1_us]: (mean N·m, its standard error from 16 batch
        means; :func:`dyno.analysis.zero_check.zero_reading`)."""
        from scipy import stats

        from dyno.analysis.zero_check import zero_reading

        _, codes, status = self._poller.streams.adc_window(int(t0_us), int(t1_us))
        z = zero_reading(codes, status, self._config().calibration)
        return z["torque_nm"], z["ci95_nm"] / float(stats.t.ppf(0.975, 15))

    def inertia_corrected(self, point: dict) -> dict:
        """``point`` with its window's I·α correction (:func:`dyno.analysis.inertia.correct_inertia`): what
        the shafts' inertias took while the speeds changed under the window, by the rig's ``[inertia]``."""
        from dyno.analysis.inertia import correct_inertia

        cfg = self._config()
        return correct_inertia(point, self._poller.streams, cfg.engine_map, cfg.inertia.engine_kg_m2,
                               cfg.inertia.secondary_kg_m2)
