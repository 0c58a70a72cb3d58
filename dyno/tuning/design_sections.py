"""The design method's sections, one function per step of Arango & Munoz (2020) (pure; equation numbers
in the docstrings are the paper's).  Composed by :func:`dyno.tuning.design.design`."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.optimize import brentq

from dyno.errors import DynoError

from dyno.tuning.design_inputs import G_M_S2, BeltSection, Requirements

# ------------------------------------------------------- section functions


def traction_forces_n(req: Requirements) -> tuple[float, float]:
    """Eqs. 1-2: climbing at top slope speed with the climb acceleration,
    and cruising flat at top speed (no acceleration)."""
    th = math.radians(req.max_slope_deg)
    v1 = req.top_speed_slope_km_h / 3.6
    v2 = req.top_speed_flat_km_h / 3.6
    drag = lambda v: 0.5 * req.air_density_kg_m3 * req.drag_coefficient * req.frontal_area_m2 * v * v  # noqa: E731
    ft1 = (req.mass_kg * req.climb_acceleration_m_s2 + req.mass_kg * G_M_S2 * math.sin(th)
           + drag(v1) + req.rolling_coefficient * req.mass_kg * G_M_S2 * math.cos(th))
    ft2 = drag(v2) + req.rolling_coefficient * req.mass_kg * G_M_S2
    return ft1, ft2


def min_driver_diameter_eq8_mm(thickness_mm: float) -> float:
    """Eq. 8 as printed: ``phi_1,min = 15.5 + 2.5 h^1.3`` [mm]."""
    return 15.5 + 2.5 * thickness_mm ** 1.3


def tight_side_tension_n(work_tension_n: float, mu: float, wrap_rad: float, belt_angle_deg: float) -> float:
    """Eqs. 12-13: ``F1 - F2 = F_work`` and ``F1/F2 = exp(mu tau / sin(phi/2))``."""
    e = math.exp(mu * wrap_rad / math.sin(math.radians(belt_angle_deg) / 2))
    return work_tension_n * e / (e - 1.0)


def bending_tension_n(section: BeltSection, diameter_mm: float) -> float:
    """Bending tension ``F_b = K_b / d``.

    The paper's eq. 17 (``eps_bb h / (0.5 phi)``) is a stress, not a force,
    as printed; we use the standard V-belt form with a per-section constant
    ``K_b`` from the catalogue (for W100 it is set so that the paper's
    2013 N at 193 mm is reproduced -- see the catalogue's source column).
    """
    return section.bending_constant_n_mm / diameter_mm


def centre_distance_eq18_mm(d_small_mm: float, d_large_mm: float, min_wrap_deg: float) -> float:
    """Eq. 18: ``tan((180 - tau_min)/2) = 0.5 (phi_2,max - phi_1,min) / C``."""
    half_deficit = math.radians((180.0 - min_wrap_deg) / 2.0)
    return 0.5 * (d_large_mm - d_small_mm) / math.tan(half_deficit)


def wrap_angles_rad(d_small_mm: float, d_large_mm: float, c_mm: float) -> tuple[float, float]:
    """Eqs. 20-21: ``tau = pi -/+ 2 asin(|phi_2 - phi_1| / 2C)``."""
    s = math.asin(abs(d_large_mm - d_small_mm) / (2.0 * c_mm))
    return math.pi - 2 * s, math.pi + 2 * s


def belt_length_mm(d1_mm: float, d2_mm: float, c_mm: float) -> float:
    """Eq. 19: ``L = sqrt(4C^2 - (phi_2 - phi_1)^2) + (phi_2 tau_out + phi_1 tau_in)/2``
    (which side is larger does not matter)."""
    small, large = sorted((d1_mm, d2_mm))
    t_in, t_out = wrap_angles_rad(small, large, c_mm)
    return math.sqrt(4 * c_mm ** 2 - (large - small) ** 2) + 0.5 * (large * t_out + small * t_in)


def lateral_displacement_mm(d_min_mm: float, d_max_mm: float, sheave_angle_deg: float) -> float:
    """Eq. 22, one moving sheave: ``sigma = (phi_max - phi_min) tan(phi/2)``.

    A single moving half-pulley travelling ``sigma`` changes the pitch
    *radius* by ``sigma / (2 tan(phi/2))``, i.e. the diameter by
    ``sigma / tan(phi/2)``; this is the reading that matches the paper's
    23.57 mm for its 193 -> ~281 mm driver.
    """
    return (d_max_mm - d_min_mm) * math.tan(math.radians(sheave_angle_deg) / 2)


def clamp_force_n(torque_nm: float, diameter_mm: float, mu: float, belt_angle_deg: float) -> float:
    """Axial force that just transmits ``torque`` without gross slip.

    Summing eqs. 23-26 over the wrap with the exponential tension of eq. 13
    gives ``F_cl = (F1 - F2) cos(phi/2) / (2 mu) = (M / r) cos(phi/2) / (2 mu)``
    (the same limit Sorge & Cammalleri quote, ``M = 2 f r F_z / cos(alpha)``).
    """
    return torque_nm / (diameter_mm / 2000.0) * math.cos(math.radians(belt_angle_deg) / 2) / (2.0 * mu)


def clamp_force_integral_n(tight_n: float, slack_n: float, belt_angle_deg: float,
                           wrap_rad: float, n: int = 400) -> float:
    """Eq. 26 summed element by element over the wrap.

    Each element of angle ``dtau`` with mean tension ``F + dF/2`` pushes the
    sheave with ``dF_cl = (F + dF/2) cos(phi/2) sin(dtau/2) / sin(phi/2)``;
    the tension rises from F2 to F1 as eq. 13 says.  The sum tends to the
    closed form of :func:`clamp_force_n` (an independent check of it).
    """
    half = math.radians(belt_angle_deg) / 2
    edges = slack_n * (tight_n / slack_n) ** (np.arange(n + 1) / n)
    mid = 0.5 * (edges[1:] + edges[:-1])
    d_tau = wrap_rad / n
    return float(np.sum(mid * math.cos(half) * math.sin(d_tau / 2) / math.sin(half)))


def weight_ramp_profile(req: Requirements, lateral_mm: float, clamp_start_n: float, clamp_end_n: float,
                        total_mass_kg: float | None = None) -> dict[str, Any]:
    """Eqs. 28-38: weight-and-ramp profile.

    Speed, weight radius and required clamp are stepped linearly over
    ``n`` differentials; each step's ramp angle is
    ``lambda_i = atan(F_cen,i / F_cl,i)`` and its axial advance
    ``dR_i F_cen,i / F_cl,i``.  The total weight mass is found (Brent) so
    the advances sum to the driver lateral displacement, as the paper does
    "by iterations".  The speed runs to the end of the shift zone
    (``shift_end_rpm``); eq. 28 as printed uses the motor's maximum speed.
    """
    n = req.n_steps
    i = np.arange(1, n + 1)
    w_rad_s = (req.shift_start_rpm + (req.shift_end_rpm - req.shift_start_rpm) / n * i) * math.pi / 30
    d_r_mm = (req.weight_radius_end_mm - req.weight_radius_start_mm) / n
    r_mm = req.weight_radius_start_mm + d_r_mm * i
    f_cl = clamp_start_n + (clamp_end_n - clamp_start_n) / n * i

    def sigma(mass):
        f_cen = mass * (r_mm / 1000) * w_rad_s ** 2
        return float(np.sum(d_r_mm * f_cen / f_cl))

    if total_mass_kg is None:
        total_mass_kg = brentq(lambda m: sigma(m) - lateral_mm, 1e-6, 1e3)
    f_cen = total_mass_kg * (r_mm / 1000) * w_rad_s ** 2
    d_sigma = d_r_mm * f_cen / f_cl
    # the first (start) point, before the first differential, for the plots
    f_cen0 = total_mass_kg * req.weight_radius_start_mm / 1000 * (req.shift_start_rpm * math.pi / 30) ** 2
    return {
        "total_mass_kg": total_mass_kg,
        "speed_rpm": (w_rad_s * 30 / math.pi).tolist(),
        "radius_mm": r_mm.tolist(),
        "axial_mm": np.cumsum(d_sigma).tolist(),
        "centrifugal_force_n": f_cen.tolist(),
        "clamp_force_n": f_cl.tolist(),
        "ramp_angle_deg": np.degrees(np.arctan(f_cen / f_cl)).tolist(),
        "mechanical_advantage": (f_cl / f_cen).tolist(),
        "start_centrifugal_force_n": f_cen0,
        "start_mechanical_advantage": clamp_start_n / f_cen0,
        "start_ramp_angle_deg": math.degrees(math.atan(f_cen0 / clamp_start_n)),
    }


def flyweight_cam_profile(req: Requirements, lateral_mm: float, clamp_start_n: float,
                          clamp_end_n: float) -> dict[str, Any]:
    """Eqs. 39-50: flyweight-cam profile.

    The paper leaves ``f_trig`` (eqs. 46-47) implicit.  We close it with
    virtual work about the flyweight pivot: turning the cam by ``d beta``
    moves the follower ``d sigma`` with ``F_cl d sigma = F_cen Y_cg d beta``
    (``F_cen`` radial at the centre of gravity, ``Y_cg = R_cg cos beta`` its
    axial arm, eqs. 39-41), integrated over ``n`` steps.  The cam pitch curve
    is the follower centre seen from the rotating flyweight, and its slope
    reproduces eq. 43, ``theta_s = atan(F_cl / F_cc)``.
    """
    n = req.n_steps
    d_sigma = lateral_mm / n
    beta = math.radians(req.flyweight_start_angle_deg)
    r_cg = req.flyweight_cg_arm_mm
    fx0, fz0 = req.follower_offset_mm
    pts, angles, slopes = [], [], []
    for i in range(1, n + 1):
        w = (req.shift_start_rpm + (req.shift_end_rpm - req.shift_start_rpm) * i / n) * math.pi / 30
        f_cl = clamp_start_n + (clamp_end_n - clamp_start_n) * i / n
        x_cg = r_cg * math.sin(beta)
        y_cg = r_cg * math.cos(beta)
        if y_cg <= 1e-9:
            raise DynoError(f"{req.name}: flyweight cam passes over centre (beta > 90 deg); "
                            "use a heavier flyweight or a longer CG arm")
        f_cen = req.flyweight_mass_kg * w ** 2 * (req.flyweight_pivot_radius_mm - x_cg) / 1000
        d_beta = f_cl * d_sigma / (f_cen * y_cg)
        beta += d_beta
        if beta >= math.pi / 2:
            raise DynoError(f"{req.name}: flyweight cam passes over centre (beta > 90 deg); "
                            "use a heavier flyweight or a longer CG arm")
        # follower centre relative to the pivot in the pulley frame, then in
        # the flyweight frame (rotate back by beta)
        fx, fz = fx0, fz0 + i * d_sigma
        c, s = math.cos(beta), math.sin(beta)
        pts.append((c * fx + s * fz, -s * fx + c * fz))
        r_cpo = math.hypot(fx, fz)
        f_cc = f_cen * y_cg / r_cpo
        slopes.append(math.degrees(math.atan(f_cl / f_cc)))
        angles.append(math.degrees(beta))
    return {
        "rotation_deg": angles[-1] - req.flyweight_start_angle_deg,
        "flyweight_angle_deg": angles,
        "profile_mm": pts,
        "contact_slope_deg": slopes,
    }


def driven_spring(req: Requirements, clamp_max_n: float, clamp_min_n: float) -> dict[str, Any]:
    """Eqs. 51-52 with the example's reading.

    The spring gives the minimum clamp at its pre-compression (eq. 52:
    ``K = F_cl,min / x_p``) and the maximum clamp fully compressed by the
    torque cam; turns from eq. 51 (``K = G d^4 / (8 D^3 n)``; the printed
    form lacks the cube) and the Wahl-corrected shear stress at max load.
    """
    k = clamp_min_n / req.spring_precompression_mm
    d, D, G = req.spring_wire_diameter_mm, req.spring_mean_diameter_mm, req.spring_shear_modulus_n_per_mm2
    turns = G * d ** 4 / (8 * D ** 3 * k)
    c_idx = D / d
    wahl = (4 * c_idx - 1) / (4 * c_idx - 4) + 0.615 / c_idx
    tau = wahl * 8 * clamp_max_n * D / (math.pi * d ** 3)
    return {
        "rate_n_per_mm": k,
        "precompression_mm": req.spring_precompression_mm,
        "max_deflection_mm": clamp_max_n / k,
        "cam_stroke_mm": (clamp_max_n - clamp_min_n) / k,
        "active_turns": turns,
        "spring_index": c_idx,
        "wahl_factor": wahl,
        "max_shear_stress_n_per_mm2": tau,
    }


def torque_cam_profile(req: Requirements, torque_max_nm: float, torque_min_nm: float,
                       f_axial_max_n: float, f_axial_min_n: float, rate_n_per_mm: float) -> dict[str, Any]:
    """Eqs. 53-63: torque-sensing (cylindrical) cam on the driven pulley.

    Torque and spring force step linearly from their maxima; tangential
    force ``F_ta = T / R_cam``; cam angle ``psi = atan(F_ta / F_sp)`` (from
    the shaft axis, so that ``tan psi`` is the mechanical advantage of eq.
    62; eq. 61 as printed has the ratio inverted); axial stroke
    ``|F_max - F_min| / K`` (eq. 58) and peripheral travel
    ``sigma_axi * MA`` (eq. 63).
    """
    n = req.n_steps
    r_cam_m = req.cam_diameter_mm / 2000
    i = np.arange(0, n + 1)
    torque = torque_max_nm + (torque_min_nm - torque_max_nm) / n * i
    f_sp = f_axial_max_n + (f_axial_min_n - f_axial_max_n) / n * i
    f_ta = torque / r_cam_m
    ma = f_ta / f_sp
    stroke = abs(f_axial_max_n - f_axial_min_n) / rate_n_per_mm
    axial = stroke / n * i
    return {
        "torque_nm": torque.tolist(),
        "spring_force_n": f_sp.tolist(),
        "tangential_force_n": f_ta.tolist(),
        "angle_deg": np.degrees(np.arctan(ma)).tolist(),
        "mechanical_advantage": ma.tolist(),
        "axial_mm": axial.tolist(),
        "peripheral_mm": np.cumsum(np.r_[0.0, np.diff(axial) * ma[1:]]).tolist(),
        "axial_stroke_mm": stroke,
        "angle_at_max_torque_deg": float(np.degrees(np.arctan(ma[0]))),
        "mechanical_advantage_at_max_torque": float(ma[0]),
        "tangential_force_at_max_torque_n": float(f_ta[0]),
    }


