"""Steady-point statistics and CVT efficiency with first-order uncertainty.

Efficiency follows the thesis (Section 9.3): the power delivered to the
secondary, measured, over the engine power read off an engine map at the
measured primary (crank) speed,

.. math:: \\eta = \\frac{T_s\\,\\omega_s}{P_{map}(n_p)}, \\qquad \\omega_s = 2\\pi n_s/60 .

Pure functions: no I/O.
"""

from __future__ import annotations

import math

import numpy as np

from dyno.analysis.engine_map import RAD_PER_S_PER_RPM, EngineMap
from dyno.analysis.engine_map_range import NoMapPower

#: Default number of batches for :func:`batch_mean`.  A 3 s steady point split
#: in 6 gives 0.5 s batches, >10 firing periods at 3000 rpm (25 Hz) and >5
#: brake-shaft revolutions, so batch means are close to independent; 6 batches
#: still leave 5 degrees of freedom for the spread.
N_BATCHES_DEFAULT = 6


def batch_mean(values, n_batches: int = N_BATCHES_DEFAULT) -> tuple[float, float]:
    """Mean of a steady point and its standard error from batch means.

    Parameters
    ----------
    values : array_like, shape (n,)
        Samples of one quantity over one steady point, in time order.
    n_batches : int
        Number of contiguous batches (>= 2, <= n).

    Returns
    -------
    mean : float
        Mean of all samples.
    sem : float
        Standard error of the mean,

        .. math:: \\mathrm{sem} = \\frac{s_B}{\\sqrt{B}}, \\qquad
                  s_B^2 = \\frac{1}{B-1}\\sum_{k=1}^{B} (\\bar x_k - \\bar{\\bar x})^2,

        where :math:`\\bar x_k` are the means of :math:`B` contiguous batches.

    Notes
    -----
    Samples within a steady point are strongly correlated: the torque and
    speed signals carry the engine's firing ripple (~25 Hz at 3000 rpm) and
    the brake-shaft once-per-revolution (thesis Fig 9.8), sampled at ~125 Hz,
    and the Hall speeds repeat until the next edge arrives.  The naive
    ``std / sqrt(n)`` treats every sample as independent and under-states the
    error several-fold.  Means of batches much longer than the correlation
    time are nearly independent, so their scatter gives an honest SEM.  With
    few batches the SEM is itself uncertain (5 dof for 6 batches: use a
    Student-t factor of 2.57, not 1.96, for a 95 % interval).  Batches are
    ``numpy.array_split`` pieces (sizes differ by at most one).
    """
    x = np.asarray(values, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"batch_mean: values must be 1-D, got shape {x.shape}")
    if isinstance(n_batches, bool) or int(n_batches) != n_batches or n_batches < 2:
        raise ValueError(f"batch_mean: n_batches must be an integer >= 2, got {n_batches!r}")
    n_batches = int(n_batches)
    if len(x) < n_batches:
        raise ValueError(f"batch_mean: {len(x)} samples cannot fill {n_batches} batches")
    if not np.all(np.isfinite(x)):
        raise ValueError("batch_mean: values must be finite (drop dropouts before averaging)")
    means = np.array([b.mean() for b in np.array_split(x, n_batches)])
    return float(x.mean()), float(means.std(ddof=1) / math.sqrt(n_batches))


def _finite(name: str, v, nonneg: bool = False) -> float:
    x = float(v)
    if not math.isfinite(x) or (nonneg and x < 0):
        raise ValueError(f"point_efficiency: {name} must be finite{' and >= 0' if nonneg else ''}, "
                         f"got {v!r}")
    return x


def point_efficiency(rpm_primary, rpm_primary_sem, rpm_secondary, rpm_secondary_sem,
                     torque_secondary_nm, torque_secondary_sem, engine_map: EngineMap) -> dict:
    """Efficiency of one steady point with its first-order standard error.

    Parameters
    ----------
    rpm_primary, rpm_primary_sem : float
        Engine (primary pulley) speed and its SEM, rpm.
    rpm_secondary, rpm_secondary_sem : float
        Secondary pulley speed and its SEM, rpm.
    torque_secondary_nm, torque_secondary_sem : float
        Secondary torque and its SEM, N·m.
    engine_map : EngineMap
        Map already at the run's ambient if a correction is wanted
        (:meth:`EngineMap.at_ambient`).

    Returns
    -------
    dict
        ``power_out_w``, ``power_out_sem_w``, ``power_in_w``,
        ``power_in_sem_w``, ``efficiency``, ``efficiency_sem`` and the map's
        ``engine_map_sha256``.

    Raises
    ------
    OutOfMapRange
        If ``rpm_primary`` is outside the engine map, or (subclass
        :class:`~dyno.analysis.engine_map.NoMapPower`) the map gives zero
        power there, as at the governor cut-off.
    ValueError
        Non-finite input or negative SEM.

    Notes
    -----
    .. math::

        P_{out} = T_s \\omega_s, \\quad P_{in} = P_{map}(n_p), \\quad
        \\eta = P_{out}/P_{in},

        \\sigma_\\eta^2 = \\left(\\frac{\\omega_s}{P_{in}}\\sigma_T\\right)^2
          + \\left(\\frac{2\\pi}{60}\\frac{T_s}{P_{in}}\\sigma_{n_s}\\right)^2
          + \\left(\\frac{\\eta}{P_{in}}\\frac{dP_{map}}{dn}\\sigma_{n_p}\\right)^2 .

    The three inputs are treated as independent (separate sensors).  Only
    the statistical scatter of the point is propagated: the engine map's own
    error and the calibration's slope error are systematic, shared by every
    point of a run, and must be quoted separately.
    """
    n_p = _finite("rpm_primary", rpm_primary)
    s_np = _finite("rpm_primary_sem", rpm_primary_sem, nonneg=True)
    n_s = _finite("rpm_secondary", rpm_secondary)
    s_ns = _finite("rpm_secondary_sem", rpm_secondary_sem, nonneg=True)
    t_s = _finite("torque_secondary_nm", torque_secondary_nm)
    s_t = _finite("torque_secondary_sem", torque_secondary_sem, nonneg=True)

    p_in = engine_map.power_w(n_p)  # raises OutOfMapRange first: the clearest error
    if not p_in > 0:
        raise NoMapPower(n_p, p_in, engine_map.rpm_min, engine_map.rpm_max, engine_map.source or "")
    dp_dn = engine_map.dpower_drpm(n_p)
    omega_s = n_s * RAD_PER_S_PER_RPM
    p_out = t_s * omega_s
    eta = p_out / p_in

    p_out_sem = math.hypot(omega_s * s_t, t_s * RAD_PER_S_PER_RPM * s_ns)
    p_in_sem = abs(dp_dn) * s_np
    eta_sem = math.sqrt((p_out_sem / p_in) ** 2 + (eta * p_in_sem / p_in) ** 2)
    return {
        "power_out_w": p_out,
        "power_out_sem_w": p_out_sem,
        "power_in_w": p_in,
        "power_in_sem_w": p_in_sem,
        "efficiency": eta,
        "efficiency_sem": eta_sem,
        "engine_map_sha256": engine_map.sha256,
    }


def add_back_loss(efficiency: float, efficiency_ci95: float, power_in_w: float, rpm_secondary: float,
                  loss_nm: float, loss_ci95_nm: float) -> tuple[float, float]:
    """Efficiency with a driven-side loss the gauge does not see added back, and its 95 % half-width
    (the point's and the loss's, independent)."""
    w = rpm_secondary * math.pi / 30.0
    eta = efficiency + loss_nm * w / power_in_w
    return eta, math.hypot(efficiency_ci95, loss_ci95_nm * w / power_in_w)
