"""Engine of the simulated rig: torque map, governor/throttle, friction, firing ripple.

The engine is a single-cylinder 4-stroke (10 hp Baja class).  Its *mean* net
torque at full throttle is the engine map (CSV ``rpm,torque_nm``), which
already contains the mechanical governor's droop near 3800 rpm, so at full
throttle the simulator reproduces the map exactly.

Part throttle (the throttle servo moves the governor's speed setting):

.. math::

    f(u, n) = \\operatorname{clip}\\left(\\frac{n_{set}(u) - n}{\\Delta n_{droop}}, 0, 1\\right),
    \\qquad n_{set}(u) = n_{idle} + \\Delta n_{idle} + u\\,(n_{map,max} - n_{idle})

    T_e(n, u) = f\\,\\bigl(T_{map}(n) + T_{fr}(n)\\bigr) - T_{fr}(n)

so ``f = 1`` gives exactly the map, ``f = 0`` gives the motoring friction
``-T_fr`` (closed throttle), and at ``u = 0`` the engine settles where the
fuelled torque just balances its friction, a little above ``n_idle``.  For
``u = 1`` the set speed lies above the map's last rpm, so ``f = 1`` wherever
the map is defined.  Killed (no ignition): ``T_e = -T_fr``.

The day's air (:mod:`dyno.sim.world`) scales the full-throttle map (``T_map`` is the day's: the standard
curve over J1349's factor); at part throttle the fuelled share ``f`` of the day's gross torque
``T_map + T_fr`` burns, and the friction ``T_fr`` is the engine's own, not scaled by the air -- as on a real
engine, whose charge the air changes and whose bearings and rings it does not (the host's part-throttle
correction keeps the friction too, with its own estimate: :mod:`dyno.analysis.part_throttle_air`).

Firing ripple: one power stroke per two revolutions.  The gas torque's
half-order harmonic has amplitude ``a_f (T_e + T_fr)`` (gross torque, so it
scales with the charge burnt); on the crank inertia ``J`` it makes the
crank angle deviate from the mean-speed angle by

.. math:: \\delta\\theta = -\\frac{a_f (T_e + T_{fr})}{J (\\omega/2)^2}
          \\sin\\left(\\tfrac{\\bar\\theta}{2} + \\varphi\\right)

(integrating ``J d^2\\theta/dt^2 = A \\sin(\\omega t / 2)`` twice).  It has
zero mean, so the mean dynamics use the mean torque only; the ripple shows
up in the Hall-edge timing (alternating long/short revolutions, measured on
the thesis rig as a 0.6-1.6 % revolution-to-revolution rpm change) and in
the torque signal.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.interpolate import PchipInterpolator


RPM_PER_RAD_S = 30.0 / math.pi
RAD_S_PER_RPM = math.pi / 30.0

#: Table spacing for the fast scalar lookup of the PCHIP map.  Linear
#: interpolation of the PCHIP curve at 0.25 rpm differs from the curve by
#: < h^2/8 max|T''| ~ 1e-6 N*m, far below anything the tests resolve.
_TABLE_STEP_RPM = 0.25


def load_engine_map(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read an engine map CSV with the host's own loader (one parser, one set of checks).

    Returns
    -------
    rpm, torque_nm : ndarray
        Strictly increasing engine speeds and the full-throttle net torque.

    Raises
    ------
    ConfigError
        Naming the file and the offending line/field.
    """
    from dyno.analysis.engine_map import load_engine_map as load

    m = load(path)
    return np.asarray(m.rpm, dtype=float), np.asarray(m.torque_nm_knots, dtype=float)


class EngineMap:
    """Full-throttle torque curve, PCHIP-interpolated, clamped outside its range.

    PCHIP (monotone, shape preserving) so that the simulated engine and the
    host's map interpolation (same method) agree, and the curve never
    overshoots between measured points.  Outside ``[rpm_min, rpm_max]`` the
    torque is clamped to the end values: no extrapolation of the curve's
    slope (the simulator must not invent torque below the map; the host's
    analysis refuses instead).
    """

    def __init__(self, rpm, torque_nm, source: str = "<array>"):
        self.rpm = np.asarray(rpm, dtype=float)
        self.torque_nm = np.asarray(torque_nm, dtype=float)
        self.source = source
        self.rpm_min = float(self.rpm[0])
        self.rpm_max = float(self.rpm[-1])
        self._pchip = PchipInterpolator(self.rpm, self.torque_nm, extrapolate=False)
        n_cells = max(int(math.ceil((self.rpm_max - self.rpm_min) / _TABLE_STEP_RPM)), 1)
        grid = np.linspace(self.rpm_min, self.rpm_max, n_cells + 1)
        self._step_rpm = (self.rpm_max - self.rpm_min) / n_cells
        self._table = [float(v) for v in self._pchip(grid)]
        self._n_cells = n_cells

    @classmethod
    def from_csv(cls, path: str | Path) -> "EngineMap":
        rpm, torque = load_engine_map(path)
        return cls(rpm, torque, source=str(path))

    def torque_exact_nm(self, rpm):
        """PCHIP map at ``rpm`` (vectorised), clamped to the end values."""
        n = np.clip(np.asarray(rpm, dtype=float), self.rpm_min, self.rpm_max)
        return self._pchip(n)

    def torque_nm_at(self, rpm: float) -> float:
        """Fast scalar lookup (table of the PCHIP curve), clamped at the ends."""
        x = (rpm - self.rpm_min) / self._step_rpm
        if x <= 0.0:
            return self._table[0]
        if x >= self._n_cells:
            return self._table[-1]
        i = int(x)
        f = x - i
        t = self._table
        return t[i] + f * (t[i + 1] - t[i])


UNGOVERNED_ZERO_RPM = 6500.0


class Engine:
    """Mean-torque engine model (see module docstring for the equations).

    Parameters are taken from :class:`dyno.sim.rig_params.RigParams`.
    """

    def __init__(self, engine_map: EngineMap, *, idle_rpm: float, idle_offset_rpm: float,
                 governor_droop_rpm: float, friction_nm: float, friction_at_3600_rpm_nm: float,
                 firing_ripple_ratio: float, inertia_kg_m2: float):
        self.map = engine_map
        self.idle_rpm = idle_rpm
        self.idle_offset_rpm = idle_offset_rpm
        self.droop_rpm = governor_droop_rpm
        self.friction_nm = friction_nm
        self.friction_quad_nm = friction_at_3600_rpm_nm - friction_nm
        self.firing_ripple_ratio = firing_ripple_ratio
        self.inertia_kg_m2 = inertia_kg_m2
        # The full-throttle set speed sits one droop band above the map's end,
        # so f = 1 on the whole map and the full-throttle torque IS the map.
        self._set_span_rpm = engine_map.rpm_max + governor_droop_rpm - (idle_rpm + idle_offset_rpm)

    def friction_nm_at(self, rpm: float) -> float:
        """Motoring friction and pumping torque (> 0), ``T_fr = a + b (n/3600)^2``."""
        q = rpm / 3600.0
        return self.friction_nm + self.friction_quad_nm * q * q

    def set_speed_rpm(self, u: float) -> float:
        """The governor's set speed at throttle ``u`` in [0, 1]: idle (with its offset) at 0, the map's top
        speed plus the droop at 1."""
        return self.idle_rpm + self.idle_offset_rpm + u * self._set_span_rpm

    def fuel_fraction(self, rpm: float, throttle_frac: float) -> float:
        """Governor fuel fraction ``f(u, n)`` in [0, 1]."""
        u = min(max(throttle_frac, 0.0), 1.0)
        n_set = self.set_speed_rpm(u)
        f = (n_set - rpm) / self.droop_rpm
        return 0.0 if f <= 0.0 else (1.0 if f >= 1.0 else f)

    def ungoverned_torque_nm(self, rpm: float) -> float:
        """Full-throttle torque with the mechanical governor failed (linkage jammed open).

        The map carries the governor's droop over its last ~450 rpm; without it the
        engine keeps making the torque it makes at the droop's start, falling
        linearly to zero at ``UNGOVERNED_ZERO_RPM`` (pumping and breathing losses of
        a small side-valve engine; a representative figure, not a measured one).
        """
        knee = self.map.rpm_max - 450.0
        if rpm <= knee:
            return self.map.torque_nm_at(rpm)
        t_knee = self.map.torque_nm_at(knee)
        return max(0.0, t_knee * (1.0 - (rpm - knee) / (UNGOVERNED_ZERO_RPM - knee)))

    def torque_nm(self, rpm: float, throttle_frac: float, running: bool, governed: bool = True) -> float:
        """Mean net crank torque (N*m) at ``rpm``; negative = friction only."""
        fr = self.friction_nm_at(rpm)
        if not running:
            return -fr
        if not governed:  # drill "overspeed": throttle stuck wide open, no governor
            return self.ungoverned_torque_nm(rpm)
        f = self.fuel_fraction(rpm, throttle_frac)
        if f >= 1.0:
            return self.map.torque_nm_at(rpm)
        return f * (self.map.torque_nm_at(rpm) + fr) - fr

    def firing_angle_amplitude_rad(self, omega_rad_s: float, torque_nm: float, rpm: float) -> float:
        """Amplitude of the crank-angle deviation due to the firing pulses.

        ``A_theta = a_f (T_e + T_fr) / (J (omega/2)^2)``, capped at 0.2 rad:
        at very low speed (start, stall) the small-perturbation formula is
        meaningless and only the edge timing uses it.
        """
        w_half = 0.5 * omega_rad_s
        if w_half < 20.0:
            return 0.0
        gross = torque_nm + self.friction_nm_at(rpm)
        if gross <= 0.0:
            return 0.0
        a = self.firing_ripple_ratio * gross / (self.inertia_kg_m2 * w_half * w_half)
        return a if a < 0.2 else 0.2
