"""The simulated rig's outputs: sensor events (Hall edges, ADC conversions) with their noise, and its truth.

The integrator of :mod:`dyno.sim.physics` advances the state one cell at a time and calls these to turn each cell's motion into
what the sensors report (:class:`RigSignals`, a mixin of :class:`~dyno.sim.physics.RigModel`), and
:meth:`RigSignals.truth` reports the true state for the tests.  Each random stream is its own
(seeded in ``RigModel.__init__``), so changing one fault's probability leaves the others unchanged.

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

from dyno.sim.engine import RPM_PER_RAD_S
from dyno.sim.sensors import angle_at, crossing_time_s

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


class RigSignals:
    """Sensor events and truth from the rig's state (a mixin of :class:`~dyno.sim.physics.RigModel`,
    whose ``__init__`` sets the state, the random streams and the signal constants these read)."""

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

    # ------------------------------------------------------------ sensor events
    def _emit_edge(self, channel: str, t: float, events: list[SensorEvent]) -> None:
        events.append(SensorEvent(channel, t))
        pb = self.params.hall_bounce_prob
        if pb > 0.0 and self._uniform_bounce() < pb:
            p = self.params
            tb = t + p.hall_bounce_min_s + (p.hall_bounce_max_s - p.hall_bounce_min_s) * self._uniform_bounce()
            events.append(SensorEvent(channel, tb))

    def _primary_edges(self, t0, h, th0, w0, a, th1, amp, events) -> None:
        """Edges where the *measured* crank angle (mean + firing ripple) crosses 2 pi k."""
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

    def _secondary_edges(self, t0, h, th0, w0, a, th1, events) -> None:
        while th1 >= TWO_PI * self._next_edge_s:
            tau = crossing_time_s(th0, w0, a, TWO_PI * self._next_edge_s)
            tau = min(max(tau, 0.0), h)
            self._emit_edge("secondary", t0 + tau, events)
            self._next_edge_s += 1

    def _adc_event(self, ta, tau, y_mean, th_e0, w_e0, a_e, th_s0, w_s0, a_s, t_gauge) -> SensorEvent:
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
        sigma = p.adc_noise_counts + p.adc_noise_counts_per_nm * abs(self._t_gauge * g)
        gain = p.adc_gain_counts_per_nm
        if p.adc_gain_rotor_tempco_per_k:  # the slope drifting as the rotor warms the shaft (a bench world)
            gain *= 1.0 + p.adc_gain_rotor_tempco_per_k * (self._rotor_c - p.ambient_temp_c)
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

    # ------------------------------------------------------------ truth
    def truth(self) -> Truth:
        """True state at the caller's time ``t_s``.

        Speeds are interpolated within the physics cell (they vary linearly
        there); torques, powers and temperatures are the cell's values.
        """
        span = self._cell_end_s - self._cell_start_s
        f = (self.t_s - self._cell_start_s) / span if span > 0.0 else 1.0
        f = 0.0 if f < 0.0 else (1.0 if f > 1.0 else f)
        w_e = self._w_e_start + f * (self._w_e - self._w_e_start)
        w_s = self._w_s_start + f * (self._w_s - self._w_s_start)
        p_in = self._t_p * w_e
        p_out = self._t_s * w_s
        eff = p_out / p_in if p_in > 1e-9 and p_out > 0.0 else 0.0
        speed_ratio = w_e / w_s if w_s > 1e-9 else 0.0
        return Truth(
            t_s=self.t_s,
            rpm_primary=w_e * RPM_PER_RAD_S,
            rpm_secondary=w_s * RPM_PER_RAD_S,
            ratio=speed_ratio,
            torque_engine_nm=self._t_e,
            torque_primary_nm=self._t_p,
            torque_secondary_nm=self._t_s,
            torque_brake_shaft_nm=self._t_gauge,
            power_in_w=p_in,
            power_out_w=p_out,
            efficiency=eff,
            rotor_temp_c=self._rotor_c,
            actuator_mm=self._act_mm,
            engine_running=self._running,
            ratio_geometric=self._ratio_geo,
            shift_travel_frac=self._x,
            power_engine_w=self._t_e * w_e,
            power_loss_w=p_in - p_out,
            brake_mu=self.brake.mu(self._rotor_c),
            brake_torque_capacity_nm=self._t_brake_cap,
            clutch_locked=self._locked,
            clutch_capacity_nm=self._cap,
            belt_slip=self._slip,
            driveline_loss_nm=self.driveline_loss_nm(w_s, self._t_s) if w_s > 0.0 else 0.0,
        )


def _interp_table(table: tuple, x: float) -> float:
    """Piecewise-linear lookup in ``((x0, y0), (x1, y1), ...)``, clamped at the ends."""
    if x <= table[0][0]:
        return table[0][1]
    for (x0, y0), (x1, y1) in zip(table, table[1:]):
        if x <= x1:
            return y0 + (y1 - y0) * (x - x0) / (x1 - x0)
    return table[-1][1]
