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

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import brentq

from dyno.errors import DynoError

from dyno.tuning.design_inputs import BeltSection, Requirements
from dyno.tuning.design_sections import (
    bending_tension_n, belt_length_mm, centre_distance_eq18_mm, clamp_force_integral_n, clamp_force_n,
    driven_spring, flyweight_cam_profile, lateral_displacement_mm, min_driver_diameter_eq8_mm,
    tight_side_tension_n, torque_cam_profile, traction_forces_n, weight_ramp_profile, wrap_angles_rad)

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


