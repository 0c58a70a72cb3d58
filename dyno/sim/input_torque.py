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

:class:`CradleLoadCell` is a part of :class:`~dyno.sim.physics.RigModel`, which asks it for the conversions
of each physics cell (:meth:`CradleLoadCell.cell_events`).
"""

from __future__ import annotations

import math

import numpy as np

from dyno.sim.rig_signals import ADC_STATUS_ERROR, SensorEvent
from dyno.sim.sensors import LowPassFilter, angle_at


class CradleLoadCell:
    """Cradle reaction -> filtered bridge signal -> second AD7171 conversions ("input" events).

    ``p``: the rig's parameters (``input_*``); ``world``: this seed's drawn gain, offset and bearing loss;
    ``engine``: the engine whose gross torque carries the firing ripple.  Fault knobs: ``error_prob``,
    ``stuck`` (every conversion repeats one code)."""

    def __init__(self, p, seed: int, world, engine) -> None:
        self.params = p
        self.engine = engine
        self.fitted = bool(p.input_torque_fitted)
        self.error_prob = p.input_error_prob
        self.stuck = False             # drill adc-stuck:input
        self._stuck_code: int | None = None
        if not self.fitted:
            return
        self._gain = world.input_gain_counts_per_nm
        self._offset = world.input_offset_counts
        self._bearing_nm = world.cradle_bearing_loss_nm
        self._filter = LowPassFilter(p.input_cutoff_hz, 2)
        self._x = self._filter.steady_state(0.0)
        self._y = 0.0
        self._period_s = 1.0 / (p.input_rate_hz * (1.0 + p.input_clock_error_frac))
        self._drift_counts_per_s = p.input_zero_drift_nm_per_min * self._gain / 60.0
        # streams of their own (SeedSequence child keys the rig's four streams do not use), so fitting
        # the channel changes none of the rig's other noise
        ss = np.random.SeedSequence(seed, spawn_key=(27,))
        s_noise, s_err, s_phase = ss.spawn(3)
        self._rng_noise = np.random.default_rng(s_noise)
        self._rng_err = np.random.default_rng(s_err)
        rng_phase = np.random.default_rng(s_phase)
        self._phase_firing = float(rng_phase.uniform(0.0, 2.0 * math.pi))
        self._next_t = float(rng_phase.uniform(0.0, self._period_s))
        self._noise_buf: list[float] = []
        self._err_buf: list[float] = []

    def _normal(self) -> float:
        if not self._noise_buf:
            self._noise_buf.extend(self._rng_noise.standard_normal(4096).tolist())
        return self._noise_buf.pop()

    def _uniform(self) -> float:
        if not self._err_buf:
            self._err_buf.extend(self._rng_err.random(4096).tolist())
        return self._err_buf.pop()

    def cell_events(self, t0: float, h: float, th_e0: float, w_e0: float, a_e: float, r_nm: float,
                    t_e: float, rpm_e: float, running: bool, events: list) -> None:
        """The cell's conversions of the cradle's load cell (mean reaction ``r_nm`` through the filter, the
        firing ripple of the engine's gross torque on it)."""
        p = self.params
        b = self._bearing_nm
        reaction = r_nm - b if r_nm > b else (r_nm + b if r_nm < -b else 0.0)  # the bearings hold a little
        y0 = self._y
        self._x, y1 = self._filter.advance(self._x, reaction, h)
        self._y = y1
        t1 = t0 + h
        gross = t_e + self.engine.friction_nm_at(rpm_e) if running else 0.0
        ripple = self.engine.firing_ripple_ratio * gross if gross > 0.0 else 0.0
        while self._next_t <= t1:
            ta = self._next_t
            tau = ta - t0
            sig = y0 + (y1 - y0) * (tau / h)
            w_e = w_e0 + a_e * tau
            if ripple and w_e > 0.0:
                gm, ph = self._filter.gain_phase(0.5 * w_e)
                th_e = angle_at(th_e0, w_e0, a_e, tau)
                sig += ripple * gm * math.sin(0.5 * th_e + self._phase_firing + ph)
            sigma = p.input_noise_counts + p.input_noise_counts_per_nm * abs(r_nm)
            code = self._offset + self._gain * sig + sigma * self._normal()
            code += self._drift_counts_per_s * ta
            code_i = min(65535, max(0, math.floor(code + 0.5)))
            status = 0
            if self.error_prob > 0.0 and self._uniform() < self.error_prob:
                status |= ADC_STATUS_ERROR
            if self.stuck:
                if self._stuck_code is None:
                    self._stuck_code = code_i
                code_i = self._stuck_code
            events.append(SensorEvent("input", ta, code_i, status))
            self._next_t = ta + self._period_s
