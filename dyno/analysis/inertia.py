"""I·alpha correction of a point measured while the speeds change (sweeps, ramps).

The torque gauge sits on the brake shaft: it reads the brake torque plus the brake shaft's own
inertia torque, so referred to the secondary it misses only the inertia *upstream* of it (the
secondary pulley, shaft and sprocket, ``J_s``).  The engine map gives the engine's steady torque;
what enters the CVT while the crank accelerates is that minus the crank side's inertia torque
(``J_e``: crank, flywheel, primary pulley)::

    T_out = T_gauge,sec + J_s alpha_s          P_in = (T_map(n_p) - J_e alpha_e) omega_p

The accelerations are the slopes of a straight line through the per-period speeds of the window
(pure: the live controller and ``dyno replay`` call this on the same events).
"""

from __future__ import annotations

import math

import numpy as np

from dyno.acquisition.rpm import rpm_per_period
from dyno.protocol import v1

RPM_TO_RAD_S = 2.0 * math.pi / 60.0


def alpha_rad_s2(streams, channel: int, t0_us: int, t1_us: int) -> float:
    """Mean angular acceleration over the window: least-squares slope of the per-period speeds."""
    edges = streams.edge_window(channel, t0_us, t1_us)
    t_mid, rpm = rpm_per_period(edges)
    t_mid = np.asarray(t_mid, dtype=float)
    rpm = np.asarray(rpm, dtype=float)
    if rpm.size < 3 or t_mid.size != rpm.size:
        return math.nan
    slope_rpm_per_us = np.polyfit(t_mid - t_mid.mean(), rpm, 1)[0]
    return float(slope_rpm_per_us * 1e6 * RPM_TO_RAD_S)


def correct_inertia(point: dict, streams, engine_map, j_engine_kg_m2: float, j_secondary_kg_m2: float) -> dict:
    """``point`` (from reduce_point) with torque, powers and efficiency corrected for I·alpha.

    Keeps the uncorrected values as ``*_uncorrected`` and records the accelerations, the inertia
    torques and the inertias used (so a replay re-applies exactly this)."""
    t0, t1 = point["t_start_us"], point["t_end_us"]
    a_e = alpha_rad_s2(streams, v1.CH_PRIMARY, t0, t1)
    a_s = alpha_rad_s2(streams, v1.CH_SECONDARY, t0, t1)
    out = dict(point)
    out.update(alpha_primary_rad_s2=a_e, alpha_secondary_rad_s2=a_s, inertia_engine_kg_m2=j_engine_kg_m2,
               inertia_secondary_kg_m2=j_secondary_kg_m2)
    if not (math.isfinite(a_e) and math.isfinite(a_s) and math.isfinite(point.get("efficiency", math.nan))):
        return out
    rp, rs = point["rpm_primary"], point["rpm_secondary"]
    if hasattr(engine_map, "at_throttle"):  # the curve the point's efficiency came from
        engine_map = engine_map.at_throttle(point.get("throttle_frac", 1.0))
    t_in_nm = float(engine_map.torque_nm(rp)) - j_engine_kg_m2 * a_e
    t_out_nm = point["torque_secondary_nm"] + j_secondary_kg_m2 * a_s
    p_in = t_in_nm * rp * RPM_TO_RAD_S
    p_out = t_out_nm * rs * RPM_TO_RAD_S
    out.update(torque_secondary_uncorrected_nm=point["torque_secondary_nm"],
               efficiency_uncorrected=point["efficiency"], power_in_uncorrected_w=point["power_in_w"],
               inertia_torque_engine_nm=j_engine_kg_m2 * a_e, inertia_torque_secondary_nm=j_secondary_kg_m2 * a_s,
               torque_secondary_nm=t_out_nm, power_in_w=p_in, power_out_w=p_out)
    if p_in > 0:
        eff = p_out / p_in
        scale = eff / point["efficiency"] if point["efficiency"] else 1.0
        out.update(efficiency=eff, efficiency_sem=point["efficiency_sem"] * abs(scale),
                   efficiency_ci95=point["efficiency_ci95"] * abs(scale))
    return out
