"""Sensors of the simulated rig: lock-in low-pass filter, ADC coding, Hall-edge timing.

Lock-in filter
--------------
The strain-gauge lock-in amplifier ends in an analog Butterworth low-pass
(``f_c`` = 15 Hz, order 2 by default, 3 possible):

.. math:: H(s) = \\frac{\\omega_c^n}{B_n(s)}

Simulated in two parts, by linearity:

* the slowly varying mean shaft torque goes through the filter's state-space
  model, discretised exactly for a zero-order-held input
  (``Phi = e^{A h}``, ``Gamma = A^{-1}(Phi - I) B``; cached per step size);
* each ripple component (engine firing order, engine revolution order, brake
  shaft order) is a sinusoid whose amplitude and frequency change slowly
  compared with its period, so its filtered value is the quasi-steady
  response ``|H(j omega)| A sin(phase + arg H(j omega))``.  Exact for
  constant speed, and it costs nothing between ADC samples.

ADC
---
AD7171: 16-bit, 125 Hz nominal output rate from an internal clock with a
small frequency error.  Each conversion gives

.. math:: code = \\operatorname{clip}(\\operatorname{round}(c_0 + G\\,(T_{sig}\\,g) + n), 0, 65535)

where ``T_sig`` is the filtered brake-shaft torque signal, ``g = 32/61``
turns it into secondary torque (the calibration, Messick eq. 9.1, is in
counts per N*m of *secondary* torque), and ``n`` is Gaussian noise with
``sigma = sigma_0 + sigma_1 |T_sec|`` counts (the load-dependent part stands
for cycle-to-cycle combustion variation and belt/pad noise, which the real
logs show growing with load).

Hall edges
----------
One falling edge per revolution, at the moment the shaft's angle crosses a
multiple of ``2 pi``.  Within an integration step the acceleration is
constant, so ``theta(tau) = theta_0 + omega_0 tau + alpha tau^2 / 2`` and the
crossing time is the root

.. math:: \\tau = \\frac{2 d}{\\omega_0 + \\sqrt{\\omega_0^2 + 2 \\alpha d}},\\qquad d = \\theta^* - \\theta_0

(the cancellation-free form), exactly consistent with the trapezoidal angle
update of the integrator.
"""

from __future__ import annotations

import cmath
import math

import numpy as np
from scipy.linalg import expm
from scipy.signal import butter, tf2ss


class LowPassFilter:
    """Analog Butterworth low-pass: exact ZOH stepping + frequency response."""

    def __init__(self, cutoff_hz: float, order: int):
        if order not in (1, 2, 3, 4):
            raise ValueError("lock-in filter order must be 1..4")
        self.cutoff_hz = cutoff_hz
        self.order = order
        wc = 2.0 * math.pi * cutoff_hz
        b, a = butter(order, wc, btype="low", analog=True)
        self._num = [float(v) for v in np.atleast_1d(b)]
        self._den = [float(v) for v in np.atleast_1d(a)]
        A, B, C, D = tf2ss(b, a)
        self._A = np.asarray(A, dtype=float)
        self._B = np.asarray(B, dtype=float).reshape(-1)
        self._C = [float(v) for v in np.asarray(C, dtype=float).reshape(-1)]
        self._D = float(np.asarray(D).reshape(-1)[0])
        self._cache: dict[float, tuple[list[list[float]], list[float]]] = {}
        self._last_h = -1.0
        self._last = None
        self.n = order
        # DC gain of this realisation: -C A^-1 B + D (should be 1 for a low-pass).
        dc = -np.asarray(self._C) @ np.linalg.solve(self._A, self._B) + self._D
        self._x_per_unit = list(np.linalg.solve(self._A, -self._B))  # steady state for u = 1
        self.dc_gain = float(dc)

    def discrete(self, h_s: float):
        """``(Phi, Gamma)`` as nested lists for step ``h_s`` (cached)."""
        key = round(h_s, 12)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        n = self.n
        M = np.zeros((n + 1, n + 1))
        M[:n, :n] = self._A * h_s
        M[:n, n] = self._B * h_s
        E = expm(M)
        phi = [[float(E[i, j]) for j in range(n)] for i in range(n)]
        gam = [float(E[i, n]) for i in range(n)]
        if len(self._cache) > 4096:
            self._cache.clear()
        self._cache[key] = (phi, gam)
        return phi, gam

    def advance(self, x: list[float], u: float, h_s: float) -> tuple[list[float], float]:
        """State after ``h_s`` with ``u`` held, and the output there."""
        if h_s == self._last_h:
            phi, gam = self._last
        else:
            phi, gam = self._last = self.discrete(h_s)
            self._last_h = h_s
        c = self._C
        if self.n == 2:   # the default order, unrolled: this runs every substep
            x0, x1 = x
            n0 = phi[0][0] * x0 + phi[0][1] * x1 + gam[0] * u
            n1 = phi[1][0] * x0 + phi[1][1] * x1 + gam[1] * u
            return [n0, n1], c[0] * n0 + c[1] * n1 + self._D * u
        n = self.n
        nx = [sum(phi[r][j] * x[j] for j in range(n)) + gam[r] * u for r in range(n)]
        return nx, self.output(nx, u)

    def steady_state(self, u: float) -> list[float]:
        """State vector of the filter settled at constant input ``u``."""
        return [float(v) * u for v in self._x_per_unit]

    def output(self, x: list[float], u: float) -> float:
        y = self._D * u
        for c, xi in zip(self._C, x):
            y += c * xi
        return y

    def response(self, freq_hz: float) -> complex:
        """``H(j 2 pi f)``."""
        s = 2j * math.pi * freq_hz
        num = 0j
        for c in self._num:
            num = num * s + c
        den = 0j
        for c in self._den:
            den = den * s + c
        return num / den

    def gain_phase(self, omega_rad_s: float) -> tuple[float, float]:
        """``(|H|, arg H)`` at angular frequency ``omega``."""
        s = 1j * omega_rad_s
        num = 0j
        for c in self._num:
            num = num * s + c
        den = 0j
        for c in self._den:
            den = den * s + c
        h = num / den
        return abs(h), cmath.phase(h)


def crossing_time_s(theta0: float, omega0: float, alpha: float, target: float) -> float:
    """Time after ``theta0`` at which the angle reaches ``target`` (constant ``alpha``).

    Returns ``inf`` if it is not reached (shaft stops first).
    """
    d = target - theta0
    if d <= 0.0:
        return 0.0
    disc = omega0 * omega0 + 2.0 * alpha * d
    if disc < 0.0:
        return math.inf
    den = omega0 + math.sqrt(disc)
    if den <= 0.0:
        return math.inf
    return 2.0 * d / den


def angle_at(theta0: float, omega0: float, alpha: float, tau: float) -> float:
    """Angle after ``tau`` at constant acceleration."""
    return theta0 + tau * (omega0 + 0.5 * alpha * tau)
