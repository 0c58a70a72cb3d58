"""Flat-belt (capstan / Gerbert) limit: the fastest and crudest model tier.

Thesis Section 2.1:

    F_2 / F_1 = exp(mu phi)                                      (2.1, capstan)
    (F_2 - F_c) / (F_1 - F_c) = exp(mu phi),  F_c = m V^2         (2.2, Gerbert)
    mu_v = mu / sin(beta)                                        (2.3, V-belt)

The tractive tension T = F - F_c is what the full model calls T, so every
function here takes tractive tensions.  :func:`capstan_point` adds Gerbert's
adhesion/sliding split (constant tension over the entry arc, exponential over
the sliding arc at the exit), Gerbert's wedge thrust and Reynolds' elastic
creep for the speed loss.  It has no seating or bending, so its torque
efficiency is 1: an upper bound used as a baseline.

Axial thrust.  A flank's friction, at angle gamma to the circumferential
direction, tilts the wedge: per unit wrap angle ``dF_z = T dphi / (2 tan(beta
+ rho'))`` with ``tan rho' = mu sin gamma``.  In the sliding arc the belt slides
circumferentially (gamma = 0, the arc where ``dT/dphi = mu_v T``): the
frictionless wedge ``T dphi / (2 tan beta)``.  In the arc without
circumferential sliding the belt is not stuck: it enters the groove and is
wedged in radially (Gerbert), so there the friction is radial (gamma = 90 deg)
and ``dF_z = T dphi / (2 tan(beta + atan mu))`` -- the same factor as the
closed form's driver thrust at rho = 0.  Against the full model (corrected,
100 N slack, ratio 0.72-1.75, 8/18 N m, 3400 rpm) the thrusts are 0.73-1.13x
(primary) and 0.60-0.79x (secondary), the thrust ratio F_s/F_p 0.59-0.95x
(docs/belt-model.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from dyno.model import geometry
from dyno.model.params import ModelParams, OperatingPoint, bad_input


def capstan_tension_ratio(wrap_rad: float, friction_coefficient: float) -> float:
    """Largest F_2/F_1 a cord can hold over ``wrap_rad`` (eq 2.1)."""
    return math.exp(friction_coefficient * wrap_rad)


def virtual_friction_coefficient(friction_coefficient: float, sheave_half_angle_rad: float) -> float:
    """Gerbert's V-belt virtual friction coefficient mu / sin(beta) (eq 2.3)."""
    return friction_coefficient / math.sin(sheave_half_angle_rad)


def max_tension_ratio(
    wrap_rad: float,
    friction_coefficient: float,
    sheave_half_angle_rad: float | None = None,
) -> float:
    """Largest tractive-tension ratio (F_2 - F_c)/(F_1 - F_c) before gross slip (eqs 2.1-2.3).

    With ``sheave_half_angle_rad`` the V-belt virtual coefficient is used, else
    the flat-belt one.  This is the bound the full model must never exceed.
    """
    mu = friction_coefficient
    if sheave_half_angle_rad is not None:
        mu = virtual_friction_coefficient(mu, sheave_half_angle_rad)
    return math.exp(mu * wrap_rad)


def wedge_thrust_n(entry_tension_n: float, held_arc_rad: float, tension_change_n: float, mu_v: float,
                   sheave_half_angle_rad: float, friction_coefficient: float) -> float:
    """Axial thrust of one pulley: radial-friction wedge over the held arc, frictionless over the sliding one.

    The held arc carries the entry tension (the belt wedges in radially there:
    friction radial); over the sliding arc ``int T dphi = dT / mu_v``
    (circumferential sliding: no radial friction).  See the module docstring.
    """
    held = entry_tension_n * held_arc_rad / (2.0 * math.tan(sheave_half_angle_rad + math.atan(friction_coefficient)))
    sliding = tension_change_n / mu_v / (2.0 * math.tan(sheave_half_angle_rad))
    return held + sliding


@dataclass(frozen=True)
class CapstanResult:
    """Outputs of the flat-belt tier, same names as the full model where they overlap."""

    r_primary_m: float
    r_secondary_m: float
    wrap_primary_rad: float
    wrap_secondary_rad: float
    tight_tension_n: float  # tractive
    slack_tension_n: float  # tractive
    centrifugal_tension_n: float
    sliding_arc_primary_rad: float
    sliding_arc_secondary_rad: float
    axial_force_primary_n: float
    axial_force_secondary_n: float
    efficiency_speed: float
    efficiency_torque: float
    gross_slip: bool

    @property
    def efficiency_overall(self) -> float:
        return self.efficiency_speed * self.efficiency_torque


def capstan_point(params: ModelParams, op: OperatingPoint) -> CapstanResult:
    """Gerbert flat-belt solution of one operating point (microseconds)."""
    belt, drive = params.belt, params.drive
    r_p, r_s = geometry.radii_for_ratio(op.ratio, belt.pitch_length_m, drive.centre_distance_m)
    phi_p, phi_s = geometry.wrap_angles_rad(r_p, r_s, drive.centre_distance_m)
    beta = drive.sheave_half_angle_rad
    mu_v = virtual_friction_coefficient(belt.friction_coefficient, beta)
    delta_t = op.primary_torque_nm / r_p
    if op.slack_tension_n is not None:
        t_slack = op.slack_tension_n
    else:
        # Driver: no circumferential sliding from the tight entry, so F_z = wedge thrust of T_t over
        # (Phi - phi_s) + of the sliding arc, with T_t = T_s + dT and phi_s = ln(T_t/T_s)/mu_v;
        # monotonic in T_s, solve by bisection.
        from scipy.optimize import brentq

        target = op.primary_axial_force_n

        def resid(ts):
            tt = ts + delta_t
            phi_slide = min(math.log(tt / ts) / mu_v, phi_p)
            return wedge_thrust_n(tt, phi_p - phi_slide, tt - ts, mu_v, beta, belt.friction_coefficient) - target

        lo, hi = 1e-6, max(target / phi_p, 1.0) * 2
        if resid(lo) > 0:
            raise bad_input("primary_axial_force_n", f"large enough to transmit {op.primary_torque_nm:g} N*m")
        while resid(hi) < 0:  # the thrust grows without bound with the tension level
            hi *= 2.0
        t_slack = brentq(resid, lo, hi, xtol=1e-9)
    t_tight = t_slack + delta_t
    ln_ratio = math.log(t_tight / t_slack)
    slide_p = ln_ratio / mu_v
    slide_s = ln_ratio / mu_v
    gross_slip = slide_p > phi_p or slide_s > phi_s
    slide_p, slide_s = min(slide_p, phi_p), min(slide_s, phi_s)
    # Driver: tight entry held over the arc without circumferential sliding; driven: slack entry held.
    mu = belt.friction_coefficient
    fz_p = wedge_thrust_n(t_tight, phi_p - slide_p, t_tight - t_slack, mu_v, beta, mu)
    fz_s = wedge_thrust_n(t_slack, phi_s - slide_s, t_tight - t_slack, mu_v, beta, mu)
    v = op.primary_speed_rad_s * r_p
    fc = belt.mass_per_length_kg_m * v * v
    ea = belt.axial_stiffness_n
    # Reynolds creep: the belt leaves the driver at the slack strain and the
    # driven pulley runs at that belt speed.
    eta_speed = (1.0 + (t_slack + fc) / ea) / (1.0 + (t_tight + fc) / ea)
    return CapstanResult(
        r_primary_m=r_p,
        r_secondary_m=r_s,
        wrap_primary_rad=phi_p,
        wrap_secondary_rad=phi_s,
        tight_tension_n=t_tight,
        slack_tension_n=t_slack,
        centrifugal_tension_n=fc,
        sliding_arc_primary_rad=slide_p,
        sliding_arc_secondary_rad=slide_s,
        axial_force_primary_n=fz_p,
        axial_force_secondary_n=fz_s,
        efficiency_speed=eta_speed,
        efficiency_torque=1.0,
        gross_slip=gross_slip,
    )
