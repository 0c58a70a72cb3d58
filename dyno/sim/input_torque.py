"""The engine-side input torque channel of the simulated rig (issue 27): a cradle load cell, a second AD7171.

The engine sits on a trunnion cradle; a load cell on its reaction arm holds the cradle against the
engine's reaction.  Taking the whole engine (block and crank) as one body, the torques on it from outside
are the cradle's reaction and the belt's pull on the crank, and the crank's inertia torque is inside it:

.. math:: R - T_p = J_e\\,\\dot\\omega_e \\quad\\Rightarrow\\quad R = T_p + J_e\\,\\dot\\omega_e = T_e

so the load cell sees the engine's **true** net torque :math:`T_e` (the world's engine, never the host's
map) with the gas torque's half-order firing ripple on it, less what the trunnion bearings hold (a
friction torque drawn per seed, ``World.cradle_bearing_loss_nm``).  The signal passes its own 2nd-order
anti-alias filter and is converted at its own rate on its own clock, with its own gain, offset, noise and
drift: each drawn per seed about the nominal (:class:`~dyno.sim.rig_params.RigParams` ``input_*``) with
the reproducibility a calibration history shows (``input_gain_drift_rel_sd``), by :mod:`dyno.sim.world`.

A mixin of :class:`~dyno.sim.physics.RigModel`: :meth:`_init_input` from its ``__init__``,
:meth:`_input_events` once per physics cell.
"""

from __future__ import annotations

import math

import numpy as np

from dyno.sim.rig_signals import ADC_STATUS_ERROR, SensorEvent
from dyno.sim.sensors import LowPassFilter, angle_at


class InputTorqueSignals:
    """Cradle reaction -> filtered bridge signal -> second AD7171 conversions ("input" events)."""

    def _init_input(self, p, seed: int) -> None:
        self.input_fitted = bool(p.input_torque_fitted)
        self.input_error_prob = p.input_error_prob
        self.input_stuck = False             # drill adc-stuck:input
        self._input_stuck_code: int | None = None
        if not self.input_fitted:
            return
        w = self.world
        self._in_gain = w.input_gain_counts_per_nm
        self._in_offset = w.input_offset_counts
        self._in_bearing_nm = w.cradle_bearing_loss_nm
        self._in_filter = LowPassFilter(p.input_cutoff_hz, 2)
        self._in_x = self._in_filter.steady_state(0.0)
        self._in_y = 0.0
        self._in_period_s = 1.0 / (p.input_rate_hz * (1.0 + p.input_clock_error_frac))
        self._in_drift_counts_per_s = p.input_zero_drift_nm_per_min * self._in_gain / 60.0
        # streams of their own (SeedSequence child keys the rig's four streams do not use), so fitting
        # the channel changes none of the rig's other noise
        ss = np.random.SeedSequence(seed, spawn_key=(27,))
        s_noise, s_err, s_phase = ss.spawn(3)
        self._in_rng_noise = np.random.default_rng(s_noise)
        self._in_rng_err = np.random.default_rng(s_err)
        rng_phase = np.random.default_rng(s_phase)
        self._in_phase_firing = float(rng_phase.uniform(0.0, 2.0 * math.pi))
        self._next_input_t = float(rng_phase.uniform(0.0, self._in_period_s))
        self._in_noise_buf: list[float] = []
        self._in_err_buf: list[float] = []

    def _in_normal(self) -> float:
        if not self._in_noise_buf:
            self._in_noise_buf.extend(self._in_rng_noise.standard_normal(4096).tolist())
        return self._in_noise_buf.pop()

    def _in_uniform(self) -> float:
        if not self._in_err_buf:
            self._in_err_buf.extend(self._in_rng_err.random(4096).tolist())
        return self._in_err_buf.pop()

    def _input_events(self, t0: float, h: float, th_e0: float, w_e0: float, a_e: float, r_nm: float,
                      t_e: float, rpm_e: float, running: bool, events: list) -> None:
        """The cell's conversions of the cradle's load cell (mean reaction ``r_nm`` through the filter, the
        firing ripple of the engine's gross torque on it)."""
        p = self.params
        b = self._in_bearing_nm
        reaction = r_nm - b if r_nm > b else (r_nm + b if r_nm < -b else 0.0)  # the bearings hold a little
        y0 = self._in_y
        self._in_x, y1 = self._in_filter.advance(self._in_x, reaction, h)
        self._in_y = y1
        t1 = t0 + h
        gross = t_e + self.engine.friction_nm_at(rpm_e) if running else 0.0
        ripple = self.engine.firing_ripple_ratio * gross if gross > 0.0 else 0.0
        while self._next_input_t <= t1:
            ta = self._next_input_t
            tau = ta - t0
            sig = y0 + (y1 - y0) * (tau / h)
            w_e = w_e0 + a_e * tau
            if ripple and w_e > 0.0:
                gm, ph = self._in_filter.gain_phase(0.5 * w_e)
                th_e = angle_at(th_e0, w_e0, a_e, tau)
                sig += ripple * gm * math.sin(0.5 * th_e + self._in_phase_firing + ph)
            sigma = p.input_noise_counts + p.input_noise_counts_per_nm * abs(r_nm)
            code = self._in_offset + self._in_gain * sig + sigma * self._in_normal()
            code += self._in_drift_counts_per_s * ta
            code_i = min(65535, max(0, math.floor(code + 0.5)))
            status = 0
            if self.input_error_prob > 0.0 and self._in_uniform() < self.input_error_prob:
                status |= ADC_STATUS_ERROR
            if self.input_stuck:
                if self._input_stuck_code is None:
                    self._input_stuck_code = code_i
                code_i = self._input_stuck_code
            events.append(SensorEvent("input", ta, code_i, status))
            self._next_input_t = ta + self._in_period_s
