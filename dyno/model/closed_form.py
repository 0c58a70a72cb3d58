r"""Closed-form axial thrusts of rubber V-belt variators (Sorge & Cammalleri).

The helical-shift paper fits the full one-dimensional belt equations with a
simple penetration profile and integrates the axial push
``F_z ~= S_t \int x d\theta`` over the inner arc.  Symbols (paper -> here):

* alpha: groove half-angle (the thesis's beta), f: friction coefficient;
* S_l: longitudinal stiffness (EA); S_t: transverse stiffness.  The thesis's
  radial stiffness k [N/m^2] gives an axial push per unit angle
  ``(k x_m / 2) r``, with ``x = x_m / r`` dimensionless, so ``S_t = k r^2 / 2``;
* k = 2 tan(alpha) S_t / S_l, k_1 = k tan(alpha + atan f)/tan(alpha),
  k_2 = k tan(alpha - atan f)/tan(alpha);
* T - mu v_b^2: the "dynamic" (tractive) belt force, the thesis's T;
* rho: dimensionless shift speed r_dot/(omega r) (0 for a steady ratio).

Equations ported (paper numbering):

* (12)/(13): exit sliding angle and the elongation gradient at the end of the
  main sliding region of the driven pulley, in terms of the asymptotic
  penetration-to-elongation ratio p = x_out / eps_out;
* (15): F(p) = 0, solved here by bracketing on (1/k_1, 1/k);
* (16): the connection point between the adhesive-like and sliding
  sub-regions;
* (17): driver thrust; (18): driven thrust; (19): torque equation;
* Delta Theta = (1/sqrt(T_T) + 1/sqrt(T_S)) sqrt(S_f) / r: the contact arc lost
  to belt arching in the free strands, subtracted from each wrap angle.

The printed eq (18) lost a fraction bar in its last denominator; integrating
the paper's own profile (linear at slope x'_in up to theta_con, then the
parabola of eq 16) gives the denominator ``p (eps'_out/eps_out)(T_T - mu v^2)
- x'_in S_l``, which is what :func:`driven_thrust_n` uses (see
docs/belt-model.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from dyno.errors import DidNotConverge
from dyno.model import geometry
from dyno.model.params import ModelParams, OperatingPoint, bad_input


def transverse_stiffness_n(radial_stiffness_n_m2: float, radius_m: float) -> float:
    """Paper's S_t [N] from the thesis's radial stiffness k [N/m^2]: S_t = k r^2 / 2."""
    return 0.5 * radial_stiffness_n_m2 * radius_m * radius_m


def stiffness_numbers(
    radial_stiffness_n_m2: float, radius_m: float, axial_stiffness_n: float, half_angle_rad: float, friction: float
) -> tuple[float, float, float]:
    """(k, k_1, k_2): the paper's dimensionless belt stiffness numbers."""
    s_t = transverse_stiffness_n(radial_stiffness_n_m2, radius_m)
    t = math.tan(half_angle_rad)
    k = 2.0 * t * s_t / axial_stiffness_n
    k1 = k * math.tan(half_angle_rad + math.atan(friction)) / t
    k2 = k * math.tan(half_angle_rad - math.atan(friction)) / t
    return k, k1, k2


def arching_deficit_rad(tight_tension_n: float, slack_tension_n: float, bending_stiffness_nm2: float, radius_m: float) -> float:
    """Delta Theta: wrap lost to belt arching in the strands (paper, end of Section 3)."""
    if tight_tension_n <= 0 or slack_tension_n <= 0:
        raise bad_input("tension", "positive tractive tensions for the arching correction")
    return (1.0 / math.sqrt(tight_tension_n) + 1.0 / math.sqrt(slack_tension_n)) * math.sqrt(bending_stiffness_nm2) / radius_m


def _q(p, k1, k2, f, alpha):
    return (1.0 - (f * math.tan(alpha)) ** 2) * (k1 * p - 1.0) * (1.0 - k2 * p)


def asymptotic_ratio(
    k: float,
    k1: float,
    k2: float,
    friction: float,
    half_angle_rad: float,
    eps_in_over_out: float,
    shift_ratio: float = 0.0,
    eps_out: float = 1.0,
    inner_arc_rad: float = 0.0,
) -> float:
    """Root p of the paper's eq (15) on (1/k_1, 1/k).

    ``eps_out`` and ``inner_arc_rad`` only matter when ``shift_ratio`` != 0.
    """
    ca = math.cos(half_angle_rad)
    r = eps_in_over_out

    def func(p):
        q = max(_q(p, k1, k2, friction, half_angle_rad), 0.0)
        sq = math.sqrt(q)
        return (
            p * q
            - shift_ratio / (eps_out * ca) * sq
            - (1.0 - k * p) * (1.0 + p - r * (1.0 + 1.0 / k1) - shift_ratio / eps_out * inner_arc_rad)
        )

    lo, hi = 1.0 / k1, 1.0 / k
    flo, fhi = func(lo), func(hi)
    if flo * fhi > 0:
        # A large shift speed can move the root; look for any sign change.
        grid = np.linspace(lo, hi, 201)
        vals = np.array([func(p) for p in grid])
        idx = np.nonzero(np.sign(vals[:-1]) * np.sign(vals[1:]) <= 0)[0]
        if idx.size == 0:
            raise DidNotConverge(
                f"closed form eq (15): no root p on (1/k1, 1/k) = ({lo:.4g}, {hi:.4g}) "
                f"for eps_in/eps_out={r:.4g}, rho={shift_ratio:.3g}"
            )
        lo, hi = grid[idx[0]], grid[idx[0] + 1]
    return brentq(func, lo, hi, xtol=1e-14, rtol=1e-12)


def driver_thrust_n(
    tight_tension_n: float,
    inner_arc_rad: float,
    half_angle_rad: float,
    friction: float,
    shift_ratio: float = 0.0,
    transverse_stiffness: float = 0.0,
    k1: float = 1.0,
) -> float:
    """Axial thrust on the driver (paper eq 17); the first term alone when rho = 0."""
    thrust = tight_tension_n * inner_arc_rad / (2.0 * math.tan(half_angle_rad + math.atan(friction)))
    if shift_ratio:
        thrust += shift_ratio * transverse_stiffness * inner_arc_rad**2 / (2.0 + k1 * (1.0 - math.copysign(1.0, shift_ratio)))
    return thrust


def driven_thrust_n(
    tight_tension_n: float,
    slack_tension_n: float,
    inner_arc_rad: float,
    half_angle_rad: float,
    friction: float,
    radial_stiffness_n_m2: float,
    radius_m: float,
    axial_stiffness_n: float,
    shift_ratio: float = 0.0,
) -> tuple[float, float]:
    """Axial thrust on the driven pulley (paper eqs 12-18); returns (F_z, p)."""
    k, k1, k2 = stiffness_numbers(radial_stiffness_n_m2, radius_m, axial_stiffness_n, half_angle_rad, friction)
    s_t = transverse_stiffness_n(radial_stiffness_n_m2, radius_m)
    s_l = axial_stiffness_n
    eps_out = tight_tension_n / s_l
    eps_in = slack_tension_n / s_l
    p = asymptotic_ratio(k, k1, k2, friction, half_angle_rad, eps_in / eps_out, shift_ratio, eps_out, inner_arc_rad)
    # eq 13: eps'_out / eps_out
    grad_ratio = math.cos(half_angle_rad) * math.sqrt(max(_q(p, k1, k2, friction, half_angle_rad), 0.0))
    x_in_slope = 0.0 if shift_ratio == 0 else 0.5 * shift_ratio * (2.0 + math.copysign(1.0, shift_ratio))
    x_out = p * eps_out
    x_in = eps_in / k1
    x_out_slope = p * grad_ratio * eps_out
    theta = inner_arc_rad
    excess = x_out - x_in - x_in_slope * theta  # what the parabola must add over the linear profile
    denom = x_out_slope - x_in_slope
    # Linear profile over the whole inner arc plus the parabolic sub-region of eq (16):
    # its extra area is (2/3) excess^2 / (x'_out - x'_in).
    integral = x_in * theta + 0.5 * x_in_slope * theta**2
    if excess > 0 and denom > 0:
        if 2.0 * excess / denom <= theta:
            integral += (2.0 / 3.0) * excess**2 / denom
        else:
            # The sliding sub-region would be longer than the arc: one parabola
            # through x_in at the entry and (x_out, x'_out) at the exit.
            integral = (2.0 * x_out + x_in) * theta / 3.0 - x_out_slope * theta**2 / 6.0
    return s_t * integral, p


@dataclass(frozen=True)
class ClosedFormResult:
    r_primary_m: float
    r_secondary_m: float
    wrap_primary_rad: float  # geometric
    wrap_secondary_rad: float
    inner_arc_primary_rad: float  # after the arching deficit
    inner_arc_secondary_rad: float
    tight_tension_n: float  # tractive
    slack_tension_n: float
    axial_force_primary_n: float
    axial_force_secondary_n: float
    penetration_ratio_p: float
    efficiency_speed: float  # Reynolds creep only (no seating loss in this tier)
    efficiency_torque: float

    @property
    def efficiency_overall(self) -> float:
        return self.efficiency_speed * self.efficiency_torque


def closed_form_point(
    params: ModelParams,
    op: OperatingPoint,
    shift_ratio_primary: float = 0.0,
    shift_ratio_secondary: float = 0.0,
    arching: bool = True,
) -> ClosedFormResult:
    """Axial thrusts on both pulleys for one operating point (tens of microseconds).

    The primary is the driver (paper subscript R), the secondary the driven
    pulley (N).  Tensions are tractive.  With a primary-axial-force operating
    point, eq (17) is inverted for T_T and eq (19) gives T_S.
    """
    belt, drive = params.belt, params.drive
    r_p, r_s = geometry.radii_for_ratio(op.ratio, belt.pitch_length_m, drive.centre_distance_m)
    phi_p, phi_s = geometry.wrap_angles_rad(r_p, r_s, drive.centre_distance_m)
    alpha, f = drive.sheave_half_angle_rad, belt.friction_coefficient
    ei = belt.bending_stiffness_nm2 if arching else 0.0
    delta_t = op.primary_torque_nm / r_p  # eq 19 with the ideal torque ratio
    _, k1_p, _ = stiffness_numbers(belt.radial_stiffness_n_m2, r_p, belt.axial_stiffness_n, alpha, f)
    s_t_p = transverse_stiffness_n(belt.radial_stiffness_n_m2, r_p)

    def inner(tt, ts, r, phi):
        return max(phi - (arching_deficit_rad(tt, ts, ei, r) if ei > 0 else 0.0), 1e-6)

    if op.slack_tension_n is not None:
        t_s = op.slack_tension_n
        t_t = t_s + delta_t
    else:
        target = op.primary_axial_force_n

        def resid(tt):
            ts = tt - delta_t
            return driver_thrust_n(tt, inner(tt, ts, r_p, phi_p), alpha, f, shift_ratio_primary, s_t_p, k1_p) - target

        lo = delta_t * (1 + 1e-9) + 1e-9
        hi = max(2 * lo, 10 * target)
        if resid(lo) > 0:
            raise bad_input("primary_axial_force_n", f"large enough to transmit {op.primary_torque_nm:g} N*m in the closed form")
        while resid(hi) < 0:
            hi *= 2
        t_t = brentq(resid, lo, hi, xtol=1e-9)
        t_s = t_t - delta_t
    th_p = inner(t_t, t_s, r_p, phi_p)
    th_s = inner(t_t, t_s, r_s, phi_s)
    fz_p = driver_thrust_n(t_t, th_p, alpha, f, shift_ratio_primary, s_t_p, k1_p)
    fz_s, p = driven_thrust_n(
        t_t, t_s, th_s, alpha, f, belt.radial_stiffness_n_m2, r_s, belt.axial_stiffness_n, shift_ratio_secondary
    )
    v = op.primary_speed_rad_s * r_p
    fc = belt.mass_per_length_kg_m * v * v
    ea = belt.axial_stiffness_n
    eta_speed = (1.0 + (t_s + fc) / ea) / (1.0 + (t_t + fc) / ea)
    return ClosedFormResult(
        r_primary_m=r_p,
        r_secondary_m=r_s,
        wrap_primary_rad=phi_p,
        wrap_secondary_rad=phi_s,
        inner_arc_primary_rad=th_p,
        inner_arc_secondary_rad=th_s,
        tight_tension_n=t_t,
        slack_tension_n=t_s,
        axial_force_primary_n=fz_p,
        axial_force_secondary_n=fz_s,
        penetration_ratio_p=p,
        efficiency_speed=eta_speed,
        efficiency_torque=1.0,
    )
