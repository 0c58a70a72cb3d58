"""What the live run screen shows, computed from the poller and controller (pure, no Textual).

The screen refreshes a few times a second and reads these; nothing here
blocks or does I/O, so a refresh costs well under a millisecond and never
delays the poller that shares the event loop.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from dyno.analysis.engine_map import NoThrottleCurve
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
    rp = poller.rpm(v1.CH_PRIMARY)
    rs = poller.rpm(v1.CH_SECONDARY)
    ratio = rp / rs if rs > 1.0 else math.nan
    torque = recent_torque_nm(poller.streams, poller.device_now_us(), controller.calibration)
    p_out = torque * rs * RAD_S_PER_RPM if not math.isnan(torque) else math.nan
    channel = getattr(controller, "input_channel", None)  # rig.toml [input_torque] (dyno.app_input)
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
        power_source=source)


TEST_STATES = ("warmup", "step", "settle", "measure")  # a test is under way (the ETA means something)


def measure_text(elapsed_s: float, plan) -> str:
    """MEASURE's clock: elapsed / cap in rig seconds, and what ends it sooner (``plan``: unscaled)."""
    if plan.target_efficiency_ci95 is not None:
        target = f"CI95 ±{plan.target_efficiency_ci95 * 100:.2g} pp"
    else:
        target = f"s.e. ≤ {plan.target_efficiency_sem * 100:.2g} pp"
    # short: with the point count and the ETA it stays on one line of 80 columns
    return (f"{min(elapsed_s, plan.max_measure_s):.0f} / {plan.max_measure_s:.0f} s "
            f"(≥ {plan.measure_s:.0f} s, until {target})")


def progress_text(state: str, n_points: int, total: int | None, eta_s: float | None) -> str:
    """``point n/~N  ETA m:ss`` of a running test (the headless progress line's words), else ''."""
    from dyno.cli.progress import eta_text, points_text

    if state not in TEST_STATES:
        return ""
    return f"{points_text(n_points, total)}  {eta_text(eta_s)}"


def discard_text(discards: list) -> str:
    """The last discarded measurement window and why (the controller measures it again), or ''."""
    if not discards:
        return ""
    d = discards[-1]
    many = f"{len(discards)} windows discarded" if len(discards) > 1 else "window discarded"
    return f"{many}; last: point {d.get('index', 0) + 1}, try {d.get('attempt', 1)}: {d.get('reason', '?')}"


def temp_colour(temp_c: float, limit_c: float, ambient_c: float = 25.0) -> tuple[str, str]:
    """(colour, marker) for the rotor temperature: green at ambient -> yellow -> red at the limit.

    The marker ('', ' warm', ' HOT', ' OVER LIMIT') carries the same meaning on
    a terminal without colour.
    """
    if math.isnan(temp_c):
        return "#888888", " (no reading)"
    f = (temp_c - ambient_c) / max(1e-9, limit_c - ambient_c)
    f = min(1.0, max(0.0, f))
    if f < 0.5:  # green -> yellow
        r, g = int(510 * f), 200
    else:  # yellow -> red
        r, g = 255, int(200 * (1.0 - f) * 2)
    marker = " OVER LIMIT" if temp_c >= limit_c else (" HOT" if f >= 0.8 else (" warm" if f >= 0.5 else ""))
    return f"#{min(r, 255):02x}{g:02x}00", marker


def last_point_text(points: list) -> str:
    """The last point's total 95 % half-width, for the points row: ``U95 ±x pp`` (its ``efficiency_u95``: the
    window's scatter with the calibration, the engine map and the air, dyno.analysis.systematic; the CI alone
    is on the measuring line)."""
    p = next((q for q in reversed(points) if isinstance(q.get("efficiency"), float)
              and math.isfinite(q["efficiency"])), None)
    if p is None:
        return ""
    return f"U95 ±{fmt(p.get('efficiency_u95', math.nan) * 100, '.1f')} pp"


def efficiency_text(v: LiveValues, loaded: bool) -> str:
    """The efficiency readout: ``—`` unless the test holds a steady load (``loaded``), ``n/a: why`` when the
    engine map gives no denominator (no curve at the commanded throttle, speed off the map)."""
    if not loaded:
        return "—"
    if math.isnan(v.efficiency):
        if v.efficiency_reason is None or not math.isnan(v.power_engine_w):
            return "—"  # no speed or no torque yet: nothing to explain
        return f"n/a: {v.efficiency_reason}"
    return fmt(v.efficiency * 100, ".1f", " %")


def fmt(x: float, spec: str = ".0f", unit: str = "") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    text = f"{x:{spec}}"
    if text.startswith("-") and float(text) == 0.0:
        text = text[1:]  # "-0" is noise around zero, not a direction
    return f"{text}{unit}"


class History:
    """Ring buffers of the last ``span_s`` of live values, for the time plot and the shift-curve trail."""

    def __init__(self, span_s: float = 30.0) -> None:
        self.span_s = span_s
        self.t: deque = deque()
        self.rpm_primary: deque = deque()
        self.rpm_secondary: deque = deque()
        self.torque_nm: deque = deque()

    def add(self, t_s: float, v: LiveValues) -> None:
        self.t.append(t_s)
        self.rpm_primary.append(v.rpm_primary)
        self.rpm_secondary.append(v.rpm_secondary)
        self.torque_nm.append(v.torque_secondary_nm)
        while self.t and t_s - self.t[0] > self.span_s:
            for d in (self.t, self.rpm_primary, self.rpm_secondary, self.torque_nm):
                d.popleft()


def overlay_inputs(points, tune=None, *, tier: str = "closed_form") -> list:
    """(secondary rpm, operating point) of each valid point, for :func:`dyno.model.overlay.predict_overlay`.

    The operating point is the slip-consistent inverse's (:mod:`dyno.model.inverse`): the geometric
    ratio and clamp that reproduce the measured speed ratio at the measured primary speed and torque,
    with ``tune`` (a :class:`~dyno.tuning.tune.Tune` or a TOML path, e.g. the run's ``tune.toml``)
    giving the clamp (flyweights minus spring at the measured rpm).  Without a tune: the thesis's
    Table 6.1 drive at 100 N of slack tension.  The primary torque is the engine-map torque the
    efficiency was computed with (power_in / omega_primary); the secondary rpm places the
    prediction on the efficiency plot.  Points whose inverse finds no steady belt (gross slip at
    the tune's clamp, spring holding the sheave open) are left out.  ``tier``: the inverse's slip,
    ``closed_form`` (microseconds per point) or ``full`` (seconds per point).
    """
    from dyno.model.inverse import invert_points

    from dyno.tuning.tune import Tune, load_tune

    if tune is not None and not isinstance(tune, Tune):
        tune = load_tune(tune)
    return [(rs, res.operating_point()) for rs, res in invert_points(points, tune, tier=tier) if res.ok]
