"""What the rig shows now, from the poller and the controller: speeds, torque, powers, efficiency, link health.

Pure reads (no I/O; time passed in), shared by the live screen (:mod:`dyno.ui.live_model`) and the web view
(:mod:`dyno.web.snapshot`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from dyno.analysis.engine_map_range import NoThrottleCurve
from dyno.protocol import v1

RAD_S_PER_RPM = 2.0 * math.pi / 60.0
TORQUE_WINDOW_US = 300_000  # the live torque is the mean of the last 0.3 s of conversions (~38 at 125 Hz)


@dataclass
class LiveValues:
    state: str
    reason: str
    paused: bool
    rpm_primary: float
    rpm_secondary: float
    ratio: float
    torque_secondary_nm: float
    power_out_w: float
    power_engine_w: float  # the engine map's curve at the commanded throttle, at the engine speed
    efficiency: float  # power_out / power_engine (meaningful in steady running only)
    rotor_temp_c: float
    rotor_temp_limit_c: float
    points: int
    frames_per_s: float
    crc_errors: int
    nacks: int
    events_lost: int
    rejected_total: int
    abort_cause: str | None
    abort_detail: str | None
    throttle_frac: float = 1.0  # as commanded: the engine-map curve power_engine_w comes from
    efficiency_reason: str | None = None  # why power_engine_w (and so the efficiency) is NaN, if known
    # the engine-side input torque channel (issue 27): then power_engine_w is T_in w_p, measured, not the map's
    torque_input_nm: float = math.nan
    power_source: str = "map"  # "map" | "input"
    run_enable: str = "n/a"  # the Nano's run-enable (dyno.acquisition.reader.run_enable_text)


def recent_torque_nm(streams, device_now_us, calibration, window_us: int = TORQUE_WINDOW_US) -> float:
    """Mean secondary torque over the last ``window_us`` of good conversions (NaN if none)."""
    if device_now_us is None or calibration is None:
        return math.nan
    _, codes, status = streams.adc_window(device_now_us - window_us, device_now_us)
    good = codes[((status & v1.ADC_STATUS_ERR) == 0) & (codes > 0) & (codes < 0xFFFF)]
    if good.size == 0:
        return math.nan
    return float(calibration.torque_secondary_nm(float(good.mean())))


def recent_input_torque_nm(streams, device_now_us, channel, window_us: int = TORQUE_WINDOW_US) -> float:
    """Mean engine torque from the input channel over the last ``window_us`` (NaN if none)."""
    if device_now_us is None or channel is None or not hasattr(streams, "input_window"):
        return math.nan
    _, codes, status = streams.input_window(device_now_us - window_us, device_now_us)
    good = codes[((status & v1.ADC_STATUS_ERR) == 0) & (codes > 0) & (codes < 0xFFFF)]
    if good.size == 0:
        return math.nan
    cal = channel.calibration
    return float((good.mean() - cal.intercept_counts) / cal.slope_counts_per_nm + channel.bearing_loss_nm)


def engine_power_w(engine_map, rpm: float, throttle_frac: float = 1.0) -> tuple[float, str | None]:
    """(engine power from the map's curve at ``throttle_frac``, None) or (NaN, why there is none).

    The curve at the commanded throttle, never the full-throttle one at part throttle (it would credit
    the engine with power it does not make) and never a blend of two throttles (see
    :meth:`dyno.analysis.engine_map.EngineMap.at_throttle`).  The reason is the screen's words (at most
    13 characters: ``n/a: <reason>`` fits the fields column); None when there is nothing to explain.
    """
    if engine_map is None:
        return math.nan, "no engine map"
    if not (rpm > 0):
        return math.nan, None  # engine stopped or no edges yet
    try:
        curve = engine_map.at_throttle(throttle_frac)
    except NoThrottleCurve:
        return math.nan, f"no {throttle_frac * 100:.0f} % curve"
    if not curve.covers(rpm):
        return math.nan, "rpm off map"
    p = float(curve.power_w(rpm))
    return (p, None) if p > 0 else (math.nan, "no map power")  # (a governor cut-off row)


def ideal_engine_rpm(engine_map) -> float:
    """The engine speed of peak power: the flat line a perfectly tuned CVT would hold."""
    import numpy as np

    if engine_map is None:
        return math.nan
    n = np.linspace(engine_map.rpm_min, engine_map.rpm_max, 400)
    return float(n[int(np.argmax(engine_map.power_w(n)))])


class RateMeter:
    """Frames per second from a running count, over the last ``window_s``."""

    def __init__(self, window_s: float = 2.0) -> None:
        self.window_s = window_s
        self._samples: deque = deque()

    def update(self, now_s: float, count: int) -> float:
        self._samples.append((now_s, count))
        while len(self._samples) > 2 and now_s - self._samples[0][0] > self.window_s:
            self._samples.popleft()
        t0, c0 = self._samples[0]
        return (count - c0) / (now_s - t0) if now_s > t0 else math.nan


def live_values(poller, controller, now_s: float, rate: RateMeter) -> LiveValues:
    from dyno.acquisition.reader import run_enable_text

    rp = poller.rpm(v1.CH_PRIMARY)
    rs = poller.rpm(v1.CH_SECONDARY)
    ratio = rp / rs if rs > 1.0 else math.nan
    torque = recent_torque_nm(poller.streams, poller.device_now_us(), controller.calibration)
    p_out = torque * rs * RAD_S_PER_RPM if not math.isnan(torque) else math.nan
    channel = getattr(controller, "input_channel", None)  # rig.toml [input_torque] (dyno.session.input_channel)
    t_in, source = math.nan, "map"
    if channel is not None:  # the engine's power measured: the map not needed
        t_in, source = recent_input_torque_nm(poller.streams, poller.device_now_us(), channel), "input"
        p_eng = t_in * rp * RAD_S_PER_RPM if math.isfinite(t_in) else math.nan
        eff_reason = None if math.isfinite(t_in) else "no input torque conversions"
    else:
        p_eng, eff_reason = engine_power_w(controller.engine_map, rp, controller.throttle_frac)
    eff = p_out / p_eng if p_eng > 0 and not math.isnan(p_out) else math.nan
    st = poller.reader.stats
    abort = controller.aborts[-1] if controller.aborts else None
    return LiveValues(
        state=controller.state.value, reason=controller.reason, paused=controller.paused,
        rpm_primary=rp, rpm_secondary=rs, ratio=ratio, torque_secondary_nm=torque, power_out_w=p_out,
        power_engine_w=p_eng, efficiency=eff, rotor_temp_c=poller.rotor_temp_c,
        rotor_temp_limit_c=controller.limits.rotor_temp_max_c, points=len(controller.points),
        frames_per_s=rate.update(now_s, st.accepted), crc_errors=int(st.rejected.get("crc", 0)),
        nacks=int(st.transport_errors.get("nack", 0)), events_lost=int(poller.reader.events_lost),
        rejected_total=int(sum(st.rejected.values())),
        abort_cause=abort["cause"] if abort else None, abort_detail=abort["detail"] if abort else None,
        throttle_frac=controller.throttle_frac, efficiency_reason=eff_reason, torque_input_nm=t_in,
        power_source=source, run_enable=run_enable_text(poller.reader))
