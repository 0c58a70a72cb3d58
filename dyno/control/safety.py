"""What trips the rig: limits and plausibility, checked on every poll and by a heartbeat task.

:class:`SafetyMonitor` is pure logic over the poller's live values (no I/O, time
passed in).  It answers one question — should the rig go to its safe state now,
and why — from three kinds of evidence:

* **limits**: rotor temperature, shaft over-speed, link silence, thermometer silence;
* **plausibility**: a sensor that stops changing, or goes quiet, while the physics
  says it must change — the Hall sensor of a shaft that must be turning, an ADC that
  repeats one 16-bit code (its own noise is ~85 counts rms) or sets its error bit on
  every conversion, a thermometer whose 0.02 K word freezes on a spinning rotor;
* **a thermal estimate** that guards the gap while the thermometer is blind:

  .. math:: \\hat T(t) = T_{last} + \\frac{1}{C_{min}} \\int_{t_{last}}^{t} T_{sec}\\,\\omega_{sec}\\,dt

  with the brake power from the measured torque and speed, no cooling and a rotor
  heat capacity below the real one, so :math:`\\hat T` bounds the truth from above.

A lagging thermometer is compensated by its known time constant: for a rising
reading the rotor is ahead of the sensor by about ``slope * (lag + age)``.

Causes (the vocabulary of ``aborts[].cause``; docs/safety.md maps drills to them):
``over_temperature``, ``overspeed``, ``comms_lost``, ``thermometer_lost``,
``sensor_fault``, ``stall`` (plus, from elsewhere: ``estop``, ``watchdog``,
``signal``, ``disk_full``, ``error``, ``safety_error``, ``timeout``, ``no_points``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from dyno.protocol import v1

TWO_PI_OVER_60 = 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class SafetyLimits:
    rotor_temp_max_c: float = 300.0
    overspeed_primary_rpm: float = 4300.0
    overspeed_secondary_rpm: float = 9000.0
    comms_timeout_s: float = 0.25
    thermometer_timeout_s: float = 2.0  # a blind over-temperature monitor is no monitor
    thermometer_lag_s: float = 0.15  # the thermometer's first-order time constant (compensated)
    thermometer_stuck_s: float = 2.0  # one identical reading this long on a spinning rotor = stuck
    rotor_heat_capacity_min_j_per_k: float = 2400.0  # below the rotor's real ~2800 J/K: the estimate errs hot
    sensor_check_rpm: float = 300.0  # a shaft turning faster than this must give Hall edges
    primary_quiet_s: float = 0.25  # no primary edge this long while the engine must run (>= 1300 rpm: 46 ms/rev)
    secondary_quiet_s: float = 0.30
    # above engagement: the secondary must turn (the stock CVTech engages at ~2,270 rpm as its tune predicts,
    # ~2,360 on the simulated rig, whose flyweights sit 3 mm in; 2,300 tripped its engagement plan)
    secondary_check_primary_rpm: float = 2600.0
    adc_error_run: int = 8  # consecutive conversions with the error bit (64 ms at 125 Hz)
    adc_stuck_run: int = 50  # identical codes in a row (0.4 s); noise makes even 5 improbable
    adc_quiet_s: float = 0.30  # no conversion this long while frames arrive
    check_period_s: float = 0.02  # heartbeat; the monitor also runs after every poll
    # Poll rate while ARMED (engine idling, throttle closed, brake released, waiting for GO): a third of the
    # rig's 150 Hz.  Each check then sees data up to 20 ms old instead of 6.7 ms; the slowest bound there,
    # adc-error's 0.1 s, is 8 conversions (64 ms) + 20 ms + the check (tests/e2e/test_e2e_armed.py).  The
    # idle cost is mostly wake-ups: one per poll, the heartbeat carried by the polls.
    armed_poll_hz: float = 50.0


@dataclass(frozen=True)
class Trip:
    cause: str
    detail: str
    trigger_s: float


class SafetyMonitor:
    """Evaluates the limits and plausibility checks; keeps the little history they need.

    Parameters
    ----------
    limits : SafetyLimits
    poller : the acquisition poller (live rpm, streams, thermometer readings, link times)
    torque_from_code : callable ADC code -> secondary torque (N*m), or None (no thermal estimate)
    """

    def __init__(self, limits: SafetyLimits, poller, torque_from_code=None) -> None:
        self.limits = limits
        self.poller = poller
        self.torque_from_code = torque_from_code
        self._last_check_s: float | None = None
        self._primary_above_since_s: float | None = None  # engine above secondary_check_primary_rpm since
        # thermometer history
        self._temp_seen_s = math.nan
        self._temps: list[tuple[float, float]] = []  # (read time, value) of the last ~1 s
        self._temp_same_since_s = math.nan
        self._temp_last_good_c = math.nan
        self._temp_last_good_s = math.nan
        self.heat_since_good_c = 0.0  # thermal estimate's rise since the last trustworthy reading
        self._temp_slope = 0.0  # C/s over the last ~0.6 s of readings
        # ADC history
        self._adc_seen = 0
        self._adc_err_run = 0
        self._adc_same_run = 0
        self._adc_last_code = -1
        self._torque_nm = 0.0
        # the engine-side input torque converter (issue 27): the same checks, once it has converted
        self._in = _ConverterRuns()
        # the Nano's run-enable drops (issue 37) seen so far: only later ones trip this monitor
        self._drops_seen = len(getattr(getattr(poller, "reader", None), "run_enable_drops", None) or ())

    # ------------------------------------------------------------------ inputs
    def _update_adc(self) -> None:
        s = self.poller.streams
        n = s.adc_total  # (absolute counts: a trim of the stream's front moves local indices, not these)
        if n == self._adc_seen:
            return
        codes, status, base = s.adc_code, s.adc_status, s.adc_trimmed
        self._adc_seen = max(self._adc_seen, base)
        err_flag = v1.ADC_STATUS_ERR
        good_sum = 0.0
        good_n = 0
        for i in range(self._adc_seen, n):
            if status[i - base] & err_flag:
                self._adc_err_run += 1
                continue
            self._adc_err_run = 0
            c = codes[i - base]
            if c == self._adc_last_code:
                self._adc_same_run += 1
            else:
                self._adc_same_run = 1
                self._adc_last_code = c
            good_sum += c
            good_n += 1
        self._adc_seen = n
        if good_n and self.torque_from_code is not None:
            self._torque_nm = float(self.torque_from_code(good_sum / good_n))

    def _update_input(self) -> None:
        s = self.poller.streams
        total = getattr(s, "input_total", 0)
        if total != self._in.seen:
            self._in.walk(s.input_code, s.input_status, s.input_trimmed, total)

    def _update_thermal(self, now: float, dt: float, rpm_secondary: float) -> None:
        p = self.poller
        lim = self.limits
        # brake power from the measured torque and secondary speed (heating only: errs hot)
        w_s = rpm_secondary * TWO_PI_OVER_60
        power_w = max(0.0, self._torque_nm) * w_s
        if dt > 0:
            self.heat_since_good_c += power_w * dt / lim.rotor_heat_capacity_min_j_per_k
        t_read = p.rotor_temp_time_s
        if math.isnan(t_read) or t_read == self._temp_seen_s:
            return
        self._temp_seen_s = t_read
        value = p.rotor_temp_c
        if self._temps and value == self._temps[-1][1]:
            if math.isnan(self._temp_same_since_s):
                self._temp_same_since_s = self._temps[-1][0]
        else:
            self._temp_same_since_s = math.nan
            self._temp_last_good_c = value
            self._temp_last_good_s = t_read
            self.heat_since_good_c = 0.0
        self._temps.append((t_read, value))
        while self._temps and self._temps[0][0] < t_read - 0.6:
            self._temps.pop(0)
        self._temp_slope = self._fit_slope_c_per_s()  # once per reading (10 Hz), not per check (150 Hz)

    def _temp_slope_c_per_s(self) -> float:
        return self._temp_slope

    def _fit_slope_c_per_s(self) -> float:
        pts = self._temps
        if len(pts) < 3:
            return 0.0
        t0 = pts[0][0]
        n = len(pts)
        mt = sum(t - t0 for t, _ in pts) / n
        mv = sum(v for _, v in pts) / n
        sxx = sum((t - t0 - mt) ** 2 for t, _ in pts)
        if sxx <= 0:
            return 0.0
        return sum((t - t0 - mt) * (v - mv) for t, v in pts) / sxx

    # ------------------------------------------------------------------ the check
    def check(self, now: float, *, loaded: bool, engine_expected: bool = False) -> Trip | None:
        """The first limit or plausibility check that fails, or None.

        ``loaded``: the test is driving the rig (throttle open, brake in use);
        ``engine_expected``: the engine has been seen running and nothing has stopped it.
        """
        lim = self.limits
        p = self.poller
        dt = 0.0 if self._last_check_s is None else max(0.0, now - self._last_check_s)
        self._last_check_s = now
        self._update_adc()
        self._update_input()
        rp, rs = p.rpm(v1.CH_PRIMARY), p.rpm(v1.CH_SECONDARY)
        self._update_thermal(now, dt, rs)

        # Link silence counts while the poller was polling: a host stall (the watchdog's business)
        # is not a lost link.  A poller that stops polling altogether is one.
        last = p.last_valid_frame_s if p.last_valid_frame_s is not None else p.started_s
        attempt = getattr(p, "last_poll_s", None)
        attempt = now if attempt is None else attempt
        if last is not None and attempt - last > lim.comms_timeout_s:
            return Trip("comms_lost", f"no valid frame for {attempt - last:.3f} s (limit {lim.comms_timeout_s} s)",
                        last + lim.comms_timeout_s)
        if last is not None and now - attempt > max(1.0, 4 * lim.comms_timeout_s):
            return Trip("comms_lost", f"the poller has not polled for {now - attempt:.2f} s", now)

        trip = self._check_run_enable(now) or self._check_temperature(now)
        if trip:
            return trip

        if rp > lim.overspeed_primary_rpm:
            return Trip("overspeed", f"primary {rp:.0f} rpm > {lim.overspeed_primary_rpm:.0f}", now)
        if rs > lim.overspeed_secondary_rpm:
            return Trip("overspeed", f"secondary {rs:.0f} rpm > {lim.overspeed_secondary_rpm:.0f}", now)

        trip = self._check_adc(now)
        if trip:
            return trip
        if loaded or engine_expected:
            trip = self._check_halls(now, rp, rs)
            if trip:
                return trip
        return None

    def _check_run_enable(self, now: float) -> Trip | None:
        """The Nano dropped its run-enable (its heartbeat, over-speed or a reset): the engine is already cut by
        wiring, so the test cannot go on; the host latches its own safe state with the Nano's cause."""
        drops = getattr(getattr(self.poller, "reader", None), "run_enable_drops", None)
        if not drops or len(drops) <= self._drops_seen:
            return None
        d = drops[self._drops_seen]
        self._drops_seen = len(drops)
        if d["cause"].startswith("reset"):
            return Trip("nano_reset", f"the Nano reset ({d['cause'][7:-1]}): its run-enable dropped and cut the engine",
                        now)
        if d["cause"].startswith("overspeed"):
            shaft = d["cause"].rpartition("_")[2]
            rpm = 60e6 / d["code"] if d["code"] else math.inf
            return Trip("overspeed", f"{shaft} {rpm:.0f} rpm (a {d['code']} us period) over the limit: the Nano's "
                        "run-enable cut the engine", now)
        return Trip("nano_heartbeat", f"the Nano's run-enable dropped ({d['cause']}: no poll for {d['code']} ms): "
                    "the engine is cut", now)

    def _check_temperature(self, now: float) -> Trip | None:
        lim = self.limits
        p = self.poller
        if p.thermometer is None or p.started_s is None:
            return None
        seen = p.rotor_temp_time_s if not math.isnan(p.rotor_temp_time_s) else p.started_s
        temp = p.rotor_temp_c
        if not math.isnan(temp):
            if temp > lim.rotor_temp_max_c:
                return Trip("over_temperature", f"rotor {temp:.1f} C > {lim.rotor_temp_max_c:.0f} C",
                            p.rotor_temp_time_s)
            slope = self._temp_slope_c_per_s()
            if slope > 0 and math.isnan(self._temp_same_since_s):
                ahead = temp + slope * (lim.thermometer_lag_s + max(0.0, now - p.rotor_temp_time_s))
                if ahead > lim.rotor_temp_max_c:
                    return Trip("over_temperature",
                                f"rotor ~{ahead:.1f} C > {lim.rotor_temp_max_c:.0f} C (reading {temp:.1f} C rising "
                                f"{slope:.1f} C/s, sensor lag {lim.thermometer_lag_s:.2f} s compensated)", now)
        if not math.isnan(self._temp_last_good_c):
            est = self._temp_last_good_c + self.heat_since_good_c
            stale_s = now - self._temp_last_good_s
            if est > lim.rotor_temp_max_c and stale_s > 0.5:
                return Trip("over_temperature", f"rotor estimated {est:.1f} C > {lim.rotor_temp_max_c:.0f} C from "
                            f"brake power (thermometer unchanged for {stale_s:.1f} s)", now)
        if now - seen > lim.thermometer_timeout_s:
            return Trip("thermometer_lost", f"no rotor temperature for {now - seen:.2f} s",
                        seen + lim.thermometer_timeout_s)
        same_since = self._temp_same_since_s
        if not math.isnan(same_since) and now - same_since >= lim.thermometer_stuck_s:
            spinning = p.rpm(v1.CH_SECONDARY) > lim.sensor_check_rpm
            if spinning or self.heat_since_good_c >= 0.5:
                return Trip("sensor_fault", f"rotor thermometer stuck at {temp:.2f} C for {now - same_since:.1f} s "
                            f"while the rotor {'turns' if spinning else 'heats'} "
                            f"(estimated +{self.heat_since_good_c:.1f} C)", now)
        return None

    def _check_adc(self, now: float) -> Trip | None:
        lim = self.limits
        if self._adc_err_run >= lim.adc_error_run:
            return Trip("sensor_fault", f"torque ADC error bit on {self._adc_err_run} conversions in a row", now)
        if self._adc_same_run >= lim.adc_stuck_run:
            return Trip("sensor_fault", f"torque ADC stuck: code {self._adc_last_code} on {self._adc_same_run} "
                        "conversions in a row (its noise alone makes a repeat rare)", now)
        s = self.poller.streams
        dev_now = self.poller.device_now_us()
        if s.adc_t and dev_now is not None and (dev_now - s.adc_t[-1]) * 1e-6 > lim.adc_quiet_s:
            return Trip("sensor_fault", f"no torque ADC conversion for {(dev_now - s.adc_t[-1]) * 1e-6:.2f} s", now)
        # the input torque converter, treated as the brake-side one (rails show as a stuck code: 0 / 65535
        # repeat, and an error bit on a whole run of conversions is its own alarm)
        r = self._in
        if r.err_run >= lim.adc_error_run:
            return Trip("sensor_fault", f"input torque ADC error bit on {r.err_run} conversions in a row", now)
        if r.same_run >= lim.adc_stuck_run:
            return Trip("sensor_fault", f"input torque ADC stuck: code {r.last_code} on {r.same_run} conversions "
                        "in a row (its noise alone makes a repeat rare)", now)
        it = getattr(s, "input_t", None)
        if it and dev_now is not None and (dev_now - it[-1]) * 1e-6 > lim.adc_quiet_s:
            return Trip("sensor_fault", f"no input torque ADC conversion for {(dev_now - it[-1]) * 1e-6:.2f} s", now)
        return None

    def _check_halls(self, now: float, rp: float, rs: float) -> Trip | None:
        lim = self.limits
        p = self.poller
        dev_now = p.device_now_us()
        if dev_now is None:
            return None
        s = p.streams

        def quiet_s(ch: int) -> float:
            e = s.edges[ch]
            return (dev_now - e[-1]) * 1e-6 if e else math.inf

        q_p, q_s = quiet_s(v1.CH_PRIMARY), quiet_s(v1.CH_SECONDARY)
        if q_p > lim.primary_quiet_s:
            if q_s > lim.secondary_quiet_s:
                return Trip("stall", f"no Hall edge on either shaft for {min(q_p, q_s):.2f} s while the engine "
                            "must run: engine stalled or both Hall sensors dead", now)
            return Trip("sensor_fault", f"primary Hall silent for {q_p:.2f} s while the secondary turns at "
                        f"{rs:.0f} rpm", now)
        if rp > lim.secondary_check_primary_rpm:
            if self._primary_above_since_s is None:
                self._primary_above_since_s = now
        else:
            self._primary_above_since_s = None
        # The engine must also have been above the check speed for the quiet time: an engine that
        # revs through engagement in a few tens of ms leaves the secondary no time for its first
        # revolution (a clutch engaging near the check speed would otherwise trip at every start).
        if (q_s > lim.secondary_quiet_s and rp > lim.secondary_check_primary_rpm
                and now - self._primary_above_since_s > lim.secondary_quiet_s):
            last = s.edges[v1.CH_SECONDARY]
            last_rpm = 60e6 / (last[-1] - last[-2]) if len(last) >= 2 and last[-1] > last[-2] else 0.0
            if last_rpm < 1000.0:
                return Trip("stall", f"secondary stopped under load (last {last_rpm:.0f} rpm) with the engine at "
                            f"{rp:.0f} rpm: clutch slipping", now)
            return Trip("sensor_fault", f"secondary Hall silent for {q_s:.2f} s (last {last_rpm:.0f} rpm) while the "
                        f"engine turns at {rp:.0f} rpm", now)
        return None


class _ConverterRuns:
    """Error-bit and identical-code runs of a converter's conversions, walked by absolute index."""

    def __init__(self) -> None:
        self.seen = 0
        self.err_run = 0
        self.same_run = 0
        self.last_code = -1

    def walk(self, codes, status, base: int, total: int) -> None:
        self.seen = max(self.seen, base)
        err_flag = v1.ADC_STATUS_ERR
        for i in range(self.seen, total):
            if status[i - base] & err_flag:
                self.err_run += 1
                continue
            self.err_run = 0
            c = codes[i - base]
            if c == self.last_code:
                self.same_run += 1
            else:
                self.same_run = 1
                self.last_code = c
        self.seen = total
