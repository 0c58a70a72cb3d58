"""The simulated rig's outputs: sensor events (Hall edges, ADC conversions) with their noise, and its truth.

The integrator of :mod:`dyno.sim.physics` advances the state one cell at a time and hands each cell's motion
to its :class:`SensorSignals`, which turns it into what the sensors report; :class:`Truth` is the true state
the model reports for the tests.  Each random stream is its own (seeded in ``RigModel.__init__``), so changing
one fault's probability leaves the others unchanged.

Signals calibrated on the thesis rig's real logs
-------------------------------------------------
Measured from ``vt-cvt-dyno-2019`` (read in place; runs 2 and 3, steady
points 1-34; run 4's ADC channel is all zeros, a dead channel, not used).
Per point: mean ADC counts -> secondary torque ``T`` (eq. 9.1), then
least-squares sinusoid fits at the engine firing frequency (``n_p/120``,
23-28 Hz), at the brake-shaft frequency (``n_s g/60``, 10-53 Hz) and at the
engine revolution frequency (46-55 Hz), and the residual.  "pre" = the
post-filter amplitude divided by ``|H(f)|`` of a 2nd-order 15 Hz Butterworth.

===========================  ==========================================  =================================
quantity                     measured                                    chosen
===========================  ==========================================  =================================
ADC rate (Arduino time)      126.6-127.0 Hz (nominal 125)                ``adc_clock_error_frac = 0.015``
firing ripple, post-filter   90-190 counts at T = 4-6 N m, 450-1000 at   ``ripple_firing_frac_table``:
                             10-23, 600-850 at 25-35                     pre/T 0.7 (T=0), 0.8 (4),
firing ripple, pre / T       0.75-0.85 at 4 N m, 1.0 at 6-7, 1.2-1.3 at  1.0 (6.5), 1.2 (9..21), 0.8 (25),
                             9-21, 0.9 at 24, 0.5 at 29, 0.42 at 35      0.5 (29), 0.42 (35)
revolution order, post       5-65 counts; pre / T 0.1-0.35               ``ripple_engine_rev_frac = 0.22``
brake-shaft order, post      < 15 counts above 35 Hz, 60-320 at 10-26 Hz ``ripple_brake_shaft_frac = 0.08``
                             (heavy load); pre / T 0.03-0.15 (outliers
                             0.3-0.6 where it meets the firing frequency)
residual (white) noise       85-130 counts std at T = 4-10 N m (one       ``adc_noise_counts = 85``,
                             run 190-200), 130-290 at 15-35; 0.5 s        ``adc_noise_counts_per_nm = 5``
                             segment means scatter as white noise would
total ADC std per point      150-240 counts light, 540-740 heavy         (reproduced, see tests/sim)
primary rpm, consecutive     mean abs difference 0.6-1.6 % of rpm         ``engine_firing_ripple_ratio = 1.8``
revolutions                  (long/short revolutions from firing)        ``engine_inertia_kg_m2 = 0.045``,
                                                                         ``hall_primary_phase_rad = 0.7``
===========================  ==========================================  =================================

Consequence for the host: with this (realistic) noise the 3 s mean of the
torque scatters by ``(85 + 5 T)/sqrt(380)`` counts, i.e. 0.4-0.65 % of the
mean torque (1 sigma) between 10 and 25 N m, and the per-point efficiency
scatters by about the same relative amount.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from dyno.sim.sensors import LowPassFilter, angle_at, crossing_time_s

TWO_PI = 2.0 * math.pi
ADC_STATUS_ERROR = 0x20


@dataclass
class SensorEvent:
    """One sensor event: a Hall falling edge or an ADC conversion."""

    channel: str          # "primary" | "secondary" | "adc"
    t_s: float            # true simulation time of the event
    code: int = 0         # ADC code (0..65535, clipped at the rails)
    status: int = 0       # AD7171 status bits; 0x20 = error bit


@dataclass
class Truth:
    """True state of the rig at the current time (for tests)."""

    t_s: float
    rpm_primary: float
    rpm_secondary: float
    ratio: float                   # primary speed / secondary speed (speed ratio, includes creep)
    torque_engine_nm: float        # mean net engine torque (no firing ripple)
    torque_primary_nm: float       # belt input torque
    torque_secondary_nm: float     # belt output torque
    torque_brake_shaft_nm: float   # torque in the instrumented brake shaft (mean, no ripple)
    power_in_w: float              # CVT input power  T_p omega_p
    power_out_w: float             # CVT output power T_s omega_s
    efficiency: float              # power_out / power_in (0 when no power flows)
    rotor_temp_c: float
    actuator_mm: float
    engine_running: bool
    ratio_geometric: float = 0.0   # r_s / r_p of the sheaves
    shift_travel_frac: float = 0.0
    power_engine_w: float = 0.0    # engine mean torque x speed
    power_loss_w: float = 0.0      # power_in - power_out (belt losses)
    brake_mu: float = 0.0
    brake_torque_capacity_nm: float = 0.0
    clutch_locked: bool = False
    clutch_capacity_nm: float = 0.0  # torque the primary can pass now (engagement)
    belt_slip: float = 0.0         # 1 - belt speed efficiency: omega_s = (1 - slip) omega_p / ratio_geometric
    # efficiency above is the belt's (the CVT's) alone; between it and the gauge the driveline takes this
    # (at the secondary, N·m; RigParams driveline_loss_*)
    driveline_loss_nm: float = 0.0


class SensorSignals:
    """Hall edges and torque-ADC conversions from each physics cell's motion (owned by
    :class:`~dyno.sim.physics.RigModel`).

    ``rng_noise``, ``rng_bounce``, ``rng_err``: the streams of the ADC noise, the Hall bounce and the ADC error
    bit; ``rng_phase`` draws the ripples' phases and the first conversion's time; ``th_s0`` is the secondary's
    starting angle (its first edge).  Fault knobs: ``adc_error_prob``, ``adc_stuck`` (every conversion repeats
    one code)."""

    def __init__(self, p, rng_noise, rng_bounce, rng_err, rng_phase, th_s0: float) -> None:
        self.params = p
        self._g = p.gear_ratio_brake_per_secondary
        self._firing_table = tuple((float(a), float(b)) for a, b in p.ripple_firing_frac_table)
        self._zero_drift_counts_per_s = p.adc_zero_drift_nm_per_min * p.adc_gain_counts_per_nm / 60.0
        self._adc_period_s = 1.0 / (p.adc_rate_hz * (1.0 + p.adc_clock_error_frac))
        self.lockin = LowPassFilter(p.lockin_cutoff_hz, p.lockin_filter_order)
        self._filt_x = self.lockin.steady_state(0.0)
        self._filt_y = 0.0
        self._rng_noise, self._rng_bounce, self._rng_err = rng_noise, rng_bounce, rng_err
        self._noise_buf: list[float] = []
        self._bounce_buf: list[float] = []
        self._err_buf: list[float] = []
        self.adc_error_prob = p.adc_error_prob
        self.adc_stuck = False              # drill adc-stuck: every conversion repeats one code
        self._adc_stuck_code: int | None = None
        self._next_edge_e = 1       # index k of the next primary edge (measured angle 2 pi k)
        self._next_edge_s = int(th_s0 // TWO_PI) + 1
        self._phase_firing = float(rng_phase.uniform(0.0, TWO_PI))
        self._phase_rev = float(rng_phase.uniform(0.0, TWO_PI))
        self._phase_brake = float(rng_phase.uniform(0.0, TWO_PI))
        self._next_adc_t = float(rng_phase.uniform(0.0, self._adc_period_s))

    # ------------------------------------------------------------ random buffers
    def _normal(self) -> float:
        buf = self._noise_buf
        if not buf:
            buf.extend(self._rng_noise.standard_normal(4096).tolist())
        return buf.pop()

    def _uniform_bounce(self) -> float:
        buf = self._bounce_buf
        if not buf:
            buf.extend(self._rng_bounce.random(4096).tolist())
        return buf.pop()

    def _uniform_err(self) -> float:
        buf = self._err_buf
        if not buf:
            buf.extend(self._rng_err.random(4096).tolist())
        return buf.pop()

    # ------------------------------------------------------------ Hall edges
    def _emit_edge(self, channel: str, t: float, events: list[SensorEvent]) -> None:
        events.append(SensorEvent(channel, t))
        pb = self.params.hall_bounce_prob
        if pb > 0.0 and self._uniform_bounce() < pb:
            p = self.params
            tb = t + p.hall_bounce_min_s + (p.hall_bounce_max_s - p.hall_bounce_min_s) * self._uniform_bounce()
            events.append(SensorEvent(channel, tb))

    def primary_edge_near(self, th1: float) -> bool:
        """The crank's mean angle ``th1`` is within the firing ripple's reach of the next primary edge."""
        return th1 > TWO_PI * self._next_edge_e - 0.25

    def primary_edges(self, t0, h, th0, w0, a, th1, amp, events) -> None:
        """Edges where the *measured* crank angle (mean + firing ripple of amplitude ``amp``) crosses 2 pi k."""
        ph = self.params.hall_primary_phase_rad
        while True:
            target = TWO_PI * self._next_edge_e
            ts = target
            if amp > 0.0:
                for _ in range(4):   # fixed point, contraction amp/2 < 0.1
                    ts = target + amp * math.sin(0.5 * ts + ph)
            if th1 < ts:
                return
            tau = crossing_time_s(th0, w0, a, ts)
            tau = min(max(tau, 0.0), h)
            self._emit_edge("primary", t0 + tau, events)
            self._next_edge_e += 1

    def secondary_edges(self, t0, h, th0, w0, a, th1, events) -> None:
        """Edges where the secondary's angle crosses 2 pi k in the cell."""
        while th1 >= TWO_PI * self._next_edge_s:
            tau = crossing_time_s(th0, w0, a, TWO_PI * self._next_edge_s)
            tau = min(max(tau, 0.0), h)
            self._emit_edge("secondary", t0 + tau, events)
            self._next_edge_s += 1

    # ------------------------------------------------------------ torque ADC
    def adc_events(self, t0, h, t_gauge, rotor_c, th_e0, w_e0, a_e, th_s0, w_s0, a_s, events) -> None:
        """The cell's lock-in filter (exact ZOH, the gauge torque ``t_gauge`` held) and its ADC conversions."""
        y0 = self._filt_y
        xf, y1 = self.lockin.advance(self._filt_x, t_gauge, h)
        self._filt_x = xf
        self._filt_y = y1
        t1 = t0 + h
        while self._next_adc_t <= t1:
            ta = self._next_adc_t
            tau = ta - t0
            y = y0 + (y1 - y0) * (tau / h)
            events.append(self._adc_event(ta, tau, y, th_e0, w_e0, a_e, th_s0, w_s0, a_s, t_gauge, rotor_c))
            self._next_adc_t = ta + self._adc_period_s

    def _adc_event(self, ta, tau, y_mean, th_e0, w_e0, a_e, th_s0, w_s0, a_s, t_gauge, rotor_c) -> SensorEvent:
        p = self.params
        g = self._g
        th_e = angle_at(th_e0, w_e0, a_e, tau)
        w_e = w_e0 + a_e * tau
        sig = y_mean
        amp_base = abs(t_gauge)
        if amp_base > 0.0 and w_e > 0.0:
            lp = self.lockin
            gm, ph = lp.gain_phase(0.5 * w_e)
            frac = _interp_table(self._firing_table, abs(t_gauge * g))
            sig += frac * amp_base * gm * math.sin(0.5 * th_e + self._phase_firing + ph)
            gm, ph = lp.gain_phase(w_e)
            sig += p.ripple_engine_rev_frac * amp_base * gm * math.sin(th_e + self._phase_rev + ph)
            w_s = w_s0 + a_s * tau
            if w_s > 0.0:
                th_b = g * angle_at(th_s0, w_s0, a_s, tau)
                gm, ph = lp.gain_phase(g * w_s)
                sig += p.ripple_brake_shaft_frac * amp_base * gm * math.sin(th_b + self._phase_brake + ph)
        t_sec = sig * g
        sigma = p.adc_noise_counts + p.adc_noise_counts_per_nm * abs(t_gauge * g)
        gain = p.adc_gain_counts_per_nm
        if p.adc_gain_rotor_tempco_per_k:  # the slope drifting as the rotor warms the shaft (a bench world)
            gain *= 1.0 + p.adc_gain_rotor_tempco_per_k * (rotor_c - p.ambient_temp_c)
        code = p.adc_offset_counts + gain * t_sec + sigma * self._normal()
        if self._zero_drift_counts_per_s:
            code += self._zero_drift_counts_per_s * ta
        code_i = math.floor(code + 0.5)
        code_i = 0 if code_i < 0 else (65535 if code_i > 65535 else code_i)
        status = 0
        if self.adc_error_prob > 0.0 and self._uniform_err() < self.adc_error_prob:
            status = ADC_STATUS_ERROR
        if self.adc_stuck:
            if self._adc_stuck_code is None:
                self._adc_stuck_code = code_i
            code_i = self._adc_stuck_code
        return SensorEvent("adc", ta, code_i, status)


def _interp_table(table: tuple, x: float) -> float:
    """Piecewise-linear lookup in ``((x0, y0), (x1, y1), ...)``, clamped at the ends."""
    if x <= table[0][0]:
        return table[0][1]
    for (x0, y0), (x1, y1) in zip(table, table[1:]):
        if x <= x1:
            return y0 + (y1 - y0) * (x - x0) / (x1 - x0)
    return table[-1][1]
