r"""A part-throttle curve at the run's air: the fuelled (indicated) torque scales, the friction does not (pure).

SAE J1349 corrects a full-throttle curve: the map's standard torque :math:`T_F` becomes :math:`T_F / c_f`
on the day (:meth:`~dyno.analysis.engine_map.EngineMap.at_ambient`, :math:`c_f` the J1349 factor).  That
factor is built for the engine's *brake* output at wide-open throttle; what the air changes is the charge
burnt, i.e. the indicated torque, while the motoring friction and pumping :math:`T_{fr}` (bearings, rings,
valve train) stay what they are.  At part throttle the governor burns a fraction of the full charge, so the
brake torque is the fuelled part minus the same friction, and dividing the whole part-throttle curve by
:math:`c_f` scales the friction too: at a light-load cell (brake torque a few N·m, friction ~2-3 N·m) that
is an error of > 5 % (issue 39).  Here, per speed:

.. math:: g(n) = \frac{T_F(n)/c_f + T_{fr}}{T_F(n) + T_{fr}},\qquad
          T_{day}(n, u) = \bigl(T_{std}(n, u) + T_{fr}\bigr)\,g(n) - T_{fr}

-- the fuelled torque scales by the ratio the J1349 full-throttle correction implies for it (so the full
curve is :math:`T_F/c_f` exactly), the friction is subtracted unscaled.

The friction estimate (not the simulator's: the host knows no engine's friction) is stated here:
:data:`FRICTION_ESTIMATE_NM` with a 95 % half-width :data:`FRICTION_U95_NM`, flat over speed.  Basis: motored
FMEP of small air-cooled single-cylinder SI engines ~0.6-1.5 bar (Heywood, *Internal Combustion Engine
Fundamentals*, ch. 13: friction mean effective pressure; small engines at the low end of automotive
figures), over the 305 cm³ swept volume of the 10 hp Baja engine, :math:`T_{fr} = \mathrm{FMEP}\,V_d/4\pi`
= 1.5-3.6 N·m.  The torque's sensitivity to the estimate, :math:`\partial T_{day}/\partial T_{fr} =
(g - 1)(1 - f)` with :math:`f = (T_{std} + T_{fr})/(T_F + T_{fr})` the fuelled fraction, times the
half-width is the curve's stated friction term (:func:`friction_u95_nm`): zero on the reference day and at
full throttle, largest at light load on a day far from the reference.
"""

from __future__ import annotations

import numpy as np

FRICTION_ESTIMATE_NM = 2.5
FRICTION_U95_NM = 1.2


def part_throttle_at_ambient(rpm, torque_std_nm, full_std_nm, cf: float,
                             friction_nm: float = FRICTION_ESTIMATE_NM) -> tuple[np.ndarray, np.ndarray]:
    """(torque on the day, its friction term's 95 % half-width), both N·m at the knots ``rpm``: a part-throttle
    curve's standard torque ``torque_std_nm`` with the full-throttle standard torque ``full_std_nm`` at the same
    speeds, the J1349 factor ``cf``.  Torque below zero (the friction wins) is clipped to 0."""
    t = np.asarray(torque_std_nm, dtype=float)
    full = np.asarray(full_std_nm, dtype=float)
    g = (full / cf + friction_nm) / (full + friction_nm)
    day = np.maximum(0.0, (t + friction_nm) * g - friction_nm)
    fuelled = np.clip((t + friction_nm) / (full + friction_nm), 0.0, 1.0)
    return day, np.abs((g - 1.0) * (1.0 - fuelled)) * FRICTION_U95_NM


def friction_u95_nm(curve, rpm) -> float:
    """The friction term of ``curve`` (an EngineMap at the day's air) at ``rpm``: 0 for a curve without one."""
    knots = getattr(curve, "friction_u95_knots_nm", None)
    if knots is None:
        return 0.0
    return float(np.interp(rpm, curve.rpm, knots))
