"""Numerical CVT design method of Arango & Munoz (2020), Appl. Sci. 10, 6238.

From route and vehicle requirements to a rubber V-belt CVT: power, fixed and
CVT ratio range, belt section, minimum driver diameter, centre distance and
belt length, lateral displacement and misalignment, clamping forces, the
weight-and-ramp profile, the flyweight-cam profile, the driven spring and the
torque-sensing cam.  Equation numbers in docstrings are the paper's.

The core is pure: :func:`design` takes a :class:`Requirements` and a list of
:class:`BeltSection` and returns a :class:`Design`.  File readers
(:func:`load_requirements`, :func:`load_belt_catalogue`) are thin.

Lengths follow the paper and are in millimetres where the name says ``_mm``;
forces N, torques N m, speeds rpm.  Where the paper's printed equations are
incomplete or disagree with its own worked numbers, the choice made here is
stated in the docstring and in ``docs/design-method.md``.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from scipy.optimize import brentq

from dyno.errors import ConfigError, DynoError

G_M_S2 = 9.81
REQ_SCHEMA = "dyno.design-requirements/1"


# ------------------------------------------------------------------ inputs


@dataclass(frozen=True)
class BeltSection:
    """One row of the belt catalogue (``calibration/belt_catalogue.csv``).

    ``bending_constant_n_mm`` is K_b of the bending tension ``F_b = K_b / d``
    (see :func:`bending_tension_n`).
    """

    section: str
    top_width_mm: float
    thickness_mm: float
    belt_angle_deg: float
    area_mm2: float
    density_kg_per_dm3: float
    bending_constant_n_mm: float
    source: str = ""


@dataclass(frozen=True)
class Requirements:
    """Route, vehicle, motor and designer choices (Sections 2.1-2.12)."""

    name: str
    # route / performance (2.1)
    max_slope_deg: float
    top_speed_slope_km_h: float
    top_speed_flat_km_h: float
    climb_acceleration_m_s2: float
    # vehicle
    mass_kg: float
    drag_coefficient: float
    frontal_area_m2: float
    air_density_kg_m3: float
    rolling_coefficient: float
    wheel_diameter_m: float
    driveline_efficiency: float
    # motor / engine (2.2)
    max_torque_nm: float
    max_torque_speed_rpm: float
    torque_at_max_power_nm: float
    max_speed_rpm: float
    accessory_power_kw: float = 0.0
    # CVT choices (2.3-2.9)
    ratio_min: float = 1.0
    belt_friction_coefficient: float = 0.5
    belt_tensile_strength_n_per_mm2: float = 4.0
    min_wrap_angle_deg: float = 160.0
    shift_start_rpm: float = 1500.0
    shift_end_rpm: float = 2500.0
    torque_at_shift_end_nm: float = 200.0
    driver_min_diameter_mm: float | None = None  # override of eq. 8
    centre_distance_mm: float | None = None  # override of eq. 18
    driven_sheave_angle_deg: float | None = None  # 2.8 anti-crossing change
    # actuators (2.10-2.12)
    n_steps: int = 50
    weight_radius_start_mm: float = 40.0
    weight_radius_end_mm: float = 120.0
    flyweight_mass_kg: float = 0.1
    flyweight_pivot_radius_mm: float = 80.0
    flyweight_cg_arm_mm: float = 30.0
    flyweight_start_angle_deg: float = 20.0
    follower_offset_mm: tuple[float, float] = (-10.0, 25.0)
    spring_mean_diameter_mm: float = 70.0
    spring_wire_diameter_mm: float = 14.0
    spring_shear_modulus_n_per_mm2: float = 79300.0
    spring_precompression_mm: float = 10.0
    cam_diameter_mm: float = 150.0


# ----------------------------------------------------------------- results


@dataclass
class Design:
    """Everything the method produces; ``to_dict`` is JSON-ready."""

    requirements: Requirements
    traction_force_climb_n: float
    traction_force_flat_n: float
    power_climb_kw: float
    power_flat_kw: float
    power_required_kw: float
    ratio_gear: float
    ratio_cvt_max: float
    ratio_total_max: float
    belt: BeltSection
    belt_min_area_mm2: float
    driver_min_diameter_eq8_mm: float
    driver_min_diameter_mm: float
    tension_work_n: float
    tension_tight_n: float
    tension_centrifugal_n: float
    tension_bending_n: float
    tension_max_n: float
    belt_speed_m_s: float
    driven_max_diameter_mm: float
    centre_distance_eq18_mm: float
    centre_distance_mm: float
    wrap_driver_deg: float
    wrap_driven_deg: float
    belt_length_mm: float
    one_to_one_diameter_mm: float
    driver_max_diameter_mm: float
    driven_min_diameter_mm: float
    lateral_displacement_driver_mm: float
    lateral_displacement_driven_mm: float
    misalignment_deg: float
    misalignment_modified_deg: float | None
    lateral_displacement_driven_modified_mm: float | None
    clamp_force_start_n: float
    clamp_force_end_n: float
    clamp_force_start_integral_n: float
    weight_ramp: dict[str, Any]
    flyweight_cam: dict[str, Any]
    spring: dict[str, Any]
    torque_cam: dict[str, Any]
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if dataclasses.is_dataclass(v):
                v = dataclasses.asdict(v)
            out[f.name] = _jsonable(v)
        return out

    def summary_rows(self) -> list[tuple[str, float | str, str]]:
        """(label, value, unit) rows for printing."""
        return [
            ("traction force, climb (eq. 1)", self.traction_force_climb_n, "N"),
            ("traction force, flat (eq. 2)", self.traction_force_flat_n, "N"),
            ("power, climb / flat (eq. 3)", f"{self.power_climb_kw:.1f} / {self.power_flat_kw:.1f}", "kW"),
            ("fixed ratio R_gear (eq. 5)", self.ratio_gear, "-"),
            ("max CVT ratio R_cvt_max (eq. 7)", self.ratio_cvt_max, "-"),
            ("max overall ratio", self.ratio_total_max, "-"),
            ("belt section", self.belt.section, ""),
            ("belt min area (eq. 10)", self.belt_min_area_mm2, "mm^2"),
            ("driver min diameter, eq. 8 as printed", self.driver_min_diameter_eq8_mm, "mm"),
            ("driver min diameter used", self.driver_min_diameter_mm, "mm"),
            ("tight-side tension F1 (eqs. 11-13)", self.tension_tight_n, "N"),
            ("centrifugal tension (eq. 14)", self.tension_centrifugal_n, "N"),
            ("bending tension", self.tension_bending_n, "N"),
            ("max belt tension (eq. 9)", self.tension_max_n, "N"),
            ("driven max diameter", self.driven_max_diameter_mm, "mm"),
            ("centre distance, eq. 18", self.centre_distance_eq18_mm, "mm"),
            ("centre distance used", self.centre_distance_mm, "mm"),
            ("wrap driver / driven (eqs. 20-21)", f"{self.wrap_driver_deg:.1f} / {self.wrap_driven_deg:.1f}", "deg"),
            ("belt length (eq. 19)", self.belt_length_mm, "mm"),
            ("1:1 diameter", self.one_to_one_diameter_mm, "mm"),
            ("lateral displacement driver / driven (eq. 22)",
             f"{self.lateral_displacement_driver_mm:.2f} / {self.lateral_displacement_driven_mm:.2f}", "mm"),
            ("misalignment (eq. 27)", self.misalignment_deg, "deg"),
            ("clamping force start / end", f"{self.clamp_force_start_n:.0f} / {self.clamp_force_end_n:.0f}", "N"),
            ("weights total mass (eqs. 28-38)", self.weight_ramp["total_mass_kg"] * 1e3, "g"),
            ("ramp angle start / end", f"{self.weight_ramp['ramp_angle_deg'][0]:.1f} / "
                                       f"{self.weight_ramp['ramp_angle_deg'][-1]:.1f}", "deg"),
            ("flyweight-cam rotation (eqs. 39-50)", self.flyweight_cam["rotation_deg"], "deg"),
            ("driven spring rate (eq. 52)", self.spring["rate_n_per_mm"], "N/mm"),
            ("driven spring active turns (eq. 51)", self.spring["active_turns"], "-"),
            ("driven spring max shear stress", self.spring["max_shear_stress_n_per_mm2"], "N/mm^2"),
            ("torque cam angle at max torque (eq. 61)", self.torque_cam["angle_at_max_torque_deg"], "deg"),
            ("torque cam mechanical advantage (eq. 62)", self.torque_cam["mechanical_advantage_at_max_torque"], "-"),
        ]


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return v


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


# ------------------------------------------------------------------ design


def design(req: Requirements, catalogue: list[BeltSection]) -> Design:
    """Run the whole method (Sections 2.2-2.12) for one set of requirements.

    Raises
    ------
    DynoError
        If no catalogue section can carry the belt tension.
    """
    notes: list[str] = []
    ft1, ft2 = traction_forces_n(req)
    v1, v2 = req.top_speed_slope_km_h / 3.6, req.top_speed_flat_km_h / 3.6
    p1, p2 = ft1 * v1 / 1e3, ft2 * v2 / 1e3
    p_req = max(p1, p2) + req.accessory_power_kw
    r_wheel = 0.5 * req.wheel_diameter_m
    eta = req.driveline_efficiency
    r_gear = r_wheel * ft2 / (req.torque_at_max_power_nm * req.ratio_min * eta)  # eq. 5
    r_cvt_max = r_wheel * ft1 / (req.max_torque_nm * r_gear * eta)  # eq. 7

    # 2.4 belt selection: smallest section whose capacity covers eq. 9
    mu = req.belt_friction_coefficient
    wrap_min = math.radians(req.min_wrap_angle_deg)
    chosen = None
    for sec in sorted(catalogue, key=lambda s: s.area_mm2):
        d_eq8 = min_driver_diameter_eq8_mm(sec.thickness_mm)
        d1 = req.driver_min_diameter_mm or d_eq8
        f_work = req.max_torque_nm / (0.5 * d1 / 1000)  # eq. 11
        f1 = tight_side_tension_n(f_work, mu, wrap_min, sec.belt_angle_deg)  # eqs. 12-13
        v_belt = math.pi / 60 * d1 / 1000 * req.max_torque_speed_rpm  # eq. 15
        f_ce = sec.area_mm2 * 1e-6 * sec.density_kg_per_dm3 * 1e3 * v_belt ** 2  # eqs. 14, 16
        f_do = bending_tension_n(sec, d1)
        total = f1 + f_ce + f_do
        if sec.area_mm2 * req.belt_tensile_strength_n_per_mm2 >= total:  # eqs. 9-10
            chosen = (sec, d_eq8, d1, f_work, f1, f_ce, f_do, total, v_belt)
            break
    if chosen is None:
        raise DynoError(f"{req.name}: no belt section in the catalogue carries the tension")
    sec, d_eq8, d1, f_work, f1, f_ce, f_do, total, v_belt = chosen
    if req.driver_min_diameter_mm:
        notes.append(f"driver minimum diameter imposed at {d1:g} mm (eq. 8 as printed gives {d_eq8:.1f} mm)")
    if v_belt > 30.0:
        notes.append(f"belt speed {v_belt:.1f} m/s exceeds ~30 m/s")

    # 2.5 centre distance and belt length
    d2_max = d1 * r_cvt_max
    c18 = centre_distance_eq18_mm(d1, d2_max, req.min_wrap_angle_deg)
    c = req.centre_distance_mm or c18
    if req.centre_distance_mm:
        notes.append(f"centre distance imposed at {c:g} mm (eq. 18 gives {c18:.1f} mm)")
    t_in, t_out = wrap_angles_rad(d1, d2_max, c)
    length = belt_length_mm(d1, d2_max, c)

    # 2.6 complementary diameters: R_cvt_min on the same belt
    if req.ratio_min == 1.0:
        d_mid = (length - 2 * c) / math.pi
        d1_max, d2_min = d_mid, d_mid
    else:
        d1_max = brentq(lambda x: belt_length_mm(x, x * req.ratio_min, c) - length, 1.0, length)
        d2_min = d1_max * req.ratio_min

    # 2.7-2.8 lateral displacement and misalignment
    sig1 = lateral_displacement_mm(d1, d1_max, sec.belt_angle_deg)
    sig2 = lateral_displacement_mm(d2_min, d2_max, sec.belt_angle_deg)
    alig = math.degrees(math.atan(abs(sig1 - sig2) / c))
    alig_mod = sig2_mod = None
    if req.driven_sheave_angle_deg:
        sig2_mod = lateral_displacement_mm(d2_min, d2_max, req.driven_sheave_angle_deg)
        alig_mod = math.degrees(math.atan(abs(sig1 - sig2_mod) / c))

    # 2.7 / 2.9 clamping forces at the start and end of the shift zone
    cl_start = clamp_force_n(req.max_torque_nm, d1, mu, sec.belt_angle_deg)
    cl_end = clamp_force_n(req.torque_at_shift_end_nm, d1_max, mu, sec.belt_angle_deg)
    f2 = f1 - f_work
    cl_int = clamp_force_integral_n(f1, f2, sec.belt_angle_deg, wrap_min)

    ramp = weight_ramp_profile(req, sig1, cl_start, cl_end)
    fcam = flyweight_cam_profile(req, sig1, cl_start, cl_end)
    spring = driven_spring(req, cl_start, cl_end)
    tcam = torque_cam_profile(req, req.max_torque_nm * r_cvt_max, req.torque_at_shift_end_nm * req.ratio_min,
                              cl_start, cl_end, spring["rate_n_per_mm"])

    return Design(
        requirements=req, traction_force_climb_n=ft1, traction_force_flat_n=ft2,
        power_climb_kw=p1, power_flat_kw=p2, power_required_kw=p_req,
        ratio_gear=r_gear, ratio_cvt_max=r_cvt_max, ratio_total_max=r_gear * r_cvt_max,
        belt=sec, belt_min_area_mm2=total / req.belt_tensile_strength_n_per_mm2,
        driver_min_diameter_eq8_mm=d_eq8, driver_min_diameter_mm=d1,
        tension_work_n=f_work, tension_tight_n=f1, tension_centrifugal_n=f_ce, tension_bending_n=f_do,
        tension_max_n=total, belt_speed_m_s=v_belt, driven_max_diameter_mm=d2_max,
        centre_distance_eq18_mm=c18, centre_distance_mm=c,
        wrap_driver_deg=math.degrees(t_in), wrap_driven_deg=math.degrees(t_out), belt_length_mm=length,
        one_to_one_diameter_mm=(length - 2 * c) / math.pi, driver_max_diameter_mm=d1_max,
        driven_min_diameter_mm=d2_min, lateral_displacement_driver_mm=sig1,
        lateral_displacement_driven_mm=sig2, misalignment_deg=alig, misalignment_modified_deg=alig_mod,
        lateral_displacement_driven_modified_mm=sig2_mod, clamp_force_start_n=cl_start,
        clamp_force_end_n=cl_end, clamp_force_start_integral_n=cl_int, weight_ramp=ramp,
        flyweight_cam=fcam, spring=spring, torque_cam=tcam, notes=notes,
    )


# ----------------------------------------------------------------- loaders

_REQ_TABLES = {
    "route": ("max_slope_deg", "top_speed_slope_km_h", "top_speed_flat_km_h", "climb_acceleration_m_s2"),
    "vehicle": ("mass_kg", "drag_coefficient", "frontal_area_m2", "air_density_kg_m3", "rolling_coefficient",
                "wheel_diameter_m", "driveline_efficiency"),
    "motor": ("max_torque_nm", "max_torque_speed_rpm", "torque_at_max_power_nm", "max_speed_rpm",
              "accessory_power_kw"),
    "cvt": ("ratio_min", "belt_friction_coefficient", "belt_tensile_strength_n_per_mm2", "min_wrap_angle_deg",
            "shift_start_rpm", "shift_end_rpm", "torque_at_shift_end_nm", "driver_min_diameter_mm",
            "centre_distance_mm", "driven_sheave_angle_deg"),
    "actuators": ("n_steps", "weight_radius_start_mm", "weight_radius_end_mm", "flyweight_mass_kg",
                  "flyweight_pivot_radius_mm", "flyweight_cg_arm_mm", "flyweight_start_angle_deg",
                  "follower_offset_mm", "spring_mean_diameter_mm", "spring_wire_diameter_mm",
                  "spring_shear_modulus_n_per_mm2", "spring_precompression_mm", "cam_diameter_mm"),
}
_OPTIONAL = {f.name for f in dataclasses.fields(Requirements)
             if f.default is not dataclasses.MISSING}


def requirements_from_dict(data: Mapping[str, Any], path: str | Path = "<requirements>") -> Requirements:
    """Validate a parsed requirements mapping (raises ConfigError)."""
    path = str(path)
    allowed_top = {"schema", "name", *(_REQ_TABLES)}
    for key in data:
        if key not in allowed_top:
            raise ConfigError(path, key, f"unknown key (allowed: {', '.join(sorted(allowed_top))})")
    if data.get("schema", REQ_SCHEMA) != REQ_SCHEMA:
        raise ConfigError(path, "schema", f"{REQ_SCHEMA!r}")
    kwargs: dict[str, Any] = {"name": str(data.get("name", Path(path).stem))}
    for table, keys in _REQ_TABLES.items():
        sub = data.get(table, {})
        if not isinstance(sub, Mapping):
            raise ConfigError(path, table, "a table")
        for key in sub:
            if key not in keys:
                raise ConfigError(path, f"{table}.{key}", f"unknown key (allowed: {', '.join(keys)})")
        for key in keys:
            fld = f"{table}.{key}"
            if key not in sub:
                if key in _OPTIONAL:
                    continue
                raise ConfigError(path, fld, "missing number")
            val = sub[key]
            if key == "follower_offset_mm":
                if (not isinstance(val, list) or len(val) != 2
                        or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in val)):
                    raise ConfigError(path, fld, "[radial_mm, axial_mm]")
                kwargs[key] = (float(val[0]), float(val[1]))
                continue
            if key == "n_steps":
                if isinstance(val, bool) or not isinstance(val, int) or val < 2:
                    raise ConfigError(path, fld, "an integer >= 2")
                kwargs[key] = val
                continue
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
                raise ConfigError(path, fld, f"a finite number, got {val!r}")
            if key not in ("max_slope_deg",) and val < 0:
                raise ConfigError(path, fld, f">= 0, got {val}")
            kwargs[key] = float(val)
    req = Requirements(**kwargs)
    if not 0 < req.driveline_efficiency <= 1:
        raise ConfigError(path, "vehicle.driveline_efficiency", "in (0, 1]")
    if not 0 < req.min_wrap_angle_deg < 180:
        raise ConfigError(path, "cvt.min_wrap_angle_deg", "in (0, 180)")
    if req.shift_end_rpm <= req.shift_start_rpm:
        raise ConfigError(path, "cvt.shift_end_rpm", "greater than cvt.shift_start_rpm")
    for key in ("mass_kg", "wheel_diameter_m", "max_torque_nm", "torque_at_max_power_nm",
                "belt_friction_coefficient", "belt_tensile_strength_n_per_mm2", "ratio_min"):
        if getattr(req, key) <= 0:
            raise ConfigError(path, key, "> 0")
    return req


def load_requirements(path: str | Path) -> Requirements:
    """Read a requirements TOML file."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(path, "<file>", f"a readable requirements file ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(path, "<toml>", f"valid TOML ({exc})") from None
    return requirements_from_dict(data, path)


_CAT_FIELDS = ("section", "top_width_mm", "thickness_mm", "belt_angle_deg", "area_mm2",
               "density_kg_per_dm3", "bending_constant_n_mm", "source")


def load_belt_catalogue(path: str | Path) -> list[BeltSection]:
    """Read the belt catalogue CSV (header: see ``_CAT_FIELDS``)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(path, "<file>", f"a readable catalogue ({exc.strerror})") from None
    rows = [r for r in csv.DictReader(line for line in text.splitlines() if not line.startswith("#"))]
    if not rows:
        raise ConfigError(path, "<rows>", "at least one belt section")
    out = []
    for n, row in enumerate(rows, start=2):
        missing = [f for f in _CAT_FIELDS[:-1] if f not in row or row[f] in (None, "")]
        if missing:
            raise ConfigError(path, f"row {n}.{missing[0]}", "a value")
        try:
            nums = [float(row[f]) for f in _CAT_FIELDS[1:-1]]
        except ValueError:
            raise ConfigError(path, f"row {n}", "numbers in every numeric column") from None
        if any(x <= 0 for x in nums):
            raise ConfigError(path, f"row {n}", "positive numbers")
        out.append(BeltSection(row["section"], *nums, source=row.get("source") or ""))
    return out
