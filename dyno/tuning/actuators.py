"""Primary and secondary actuator forces of a mechanical CVT.

Functional API (pure, numpy-broadcasting where cheap); every name carries its
unit.  The two entry points most callers need:

* :func:`primary_axial_force_n` -- net clamp the primary puts on the belt
  (flyweights minus spring) at an engine speed and primary pitch radius;
* :func:`secondary_axial_force_n` -- clamp of the secondary (spring plus
  helix torque feedback) at a belt torque and secondary pitch radius.

Sign convention: positive axial force closes the pulley onto the belt.

Sheave travel is measured from the low-ratio position (primary open, belt at
``drive.primary_radius_min_m``; secondary closed at the matching radius) and
tied to the pitch radius by ``dz = 2 tan(alpha) dr`` (Sorge & Cammalleri eq.
20a): only one half-pulley moves, so the belt sinks by ``dz / (2 tan alpha)``.

References
----------
Messick 2018 (thesis) Section 9.4.1, eqs. 9.2-9.3; Sorge & Cammalleri,
"Helical Shift Mechanics of Rubber V-Belt Variators", eqs. 11, 20-22.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.optimize import brentq

from dyno.tuning.geometry import secondary_radius_for_primary_m
from dyno.tuning.tune import FlyweightProfile, RollerTrack, Tune, TorqueSplit

RPM_TO_RAD_S = math.pi / 30.0

# Eq. 11 is a regression over the cases of Sorge & Cammalleri Fig. 8; far
# outside them (belt torque -> 0 with a finite clamp) the 3/2 power blows up.
# The sliding-half share is kept inside this band, which still allows the
# negative share the paper reports for the faster half-pulley.
TORQUE_FRACTION_MIN = -0.5
TORQUE_FRACTION_MAX = 1.5


# ---------------------------------------------------------------- geometry


def tan_alpha(tune: Tune) -> float:
    """tan of the groove half-angle."""
    return math.tan(math.radians(tune.drive.sheave_half_angle_deg))


def primary_sheave_travel_m(tune: Tune, primary_radius_m):
    """Primary moving-sheave travel from the low-ratio stop (eq. 20a).

    ``z_p = 2 tan(alpha) (r_p - r_p,min)``, clipped to the travel range.
    """
    d = tune.drive
    rp = np.clip(np.asarray(primary_radius_m, dtype=float), d.primary_radius_min_m, d.primary_radius_max_m)
    return 2.0 * tan_alpha(tune) * (rp - d.primary_radius_min_m)


def primary_full_travel_m(tune: Tune) -> float:
    """Moving-sheave travel from low ratio to full shift."""
    return float(primary_sheave_travel_m(tune, tune.drive.primary_radius_max_m))


def secondary_radius_m(tune: Tune, primary_radius_m):
    """Secondary pitch radius for a primary radius at fixed belt length."""
    d = tune.drive
    return secondary_radius_for_primary_m(primary_radius_m, d.belt_pitch_length_m, d.centre_distance_m)


def secondary_radius_closed_m(tune: Tune) -> float:
    """Secondary pitch radius at low ratio (secondary fully closed)."""
    return float(secondary_radius_m(tune, tune.drive.primary_radius_min_m))


def secondary_sheave_travel_m(tune: Tune, secondary_radius_m_):
    """Secondary opening travel ``z_s = 2 tan(alpha) (r_s,closed - r_s)``.

    This is Sorge's ``-2 dr_N tan(alpha)`` (> 0), the spring compression of
    eq. 22.  Clipped at 0 (the sheave cannot close past its stop).
    """
    rs = np.asarray(secondary_radius_m_, dtype=float)
    return np.maximum(2.0 * tan_alpha(tune) * (secondary_radius_closed_m(tune) - rs), 0.0)


# ---------------------------------------------------------------- primary


@lru_cache(maxsize=64)
def _profile_interp(profile: FlyweightProfile) -> PchipInterpolator:
    # PCHIP: shape preserving, so a monotone measured profile stays monotone
    # and its derivative (the mechanical advantage) has no spurious wiggles.
    return PchipInterpolator(np.asarray(profile.sheave_travel_m), np.asarray(profile.radius_m), extrapolate=True)


def flyweight_radius_m(profile: FlyweightProfile, sheave_travel_m):
    """Flyweight centre-of-mass radius and ``dr/dz`` at a sheave travel.

    Returns
    -------
    radius_m, radial_per_axial : ndarray
        ``r(z)`` and the mechanical advantage ``dD_R/dD_A = dr/dz`` of
        Messick eq. 9.2.  ``z`` is clipped to the tabulated range.
    """
    z = np.clip(np.asarray(sheave_travel_m, dtype=float), profile.sheave_travel_m[0], profile.sheave_travel_m[-1])
    interp = _profile_interp(profile)
    return interp(z), interp.derivative()(z)


def sliding_mass_force_n(profile: FlyweightProfile, speed_rpm, sheave_travel_m):
    """Centrifugal axial force of sliding flyweights (Messick eq. 9.2).

    .. math:: F_A = n\\, m\\, r(z)\\, \\frac{\\Delta D_R}{\\Delta D_A}\\, \\omega^2

    i.e. virtual work: the radial centrifugal force ``n m r omega^2`` moving
    ``dr`` does the work of the axial force moving ``dz``.  Friction is
    neglected, as in the thesis.
    """
    omega = np.asarray(speed_rpm, dtype=float) * RPM_TO_RAD_S
    r, drdz = flyweight_radius_m(profile, sheave_travel_m)
    return profile.count * profile.mass_each_kg * r * drdz * omega ** 2


def roller_position(roller: RollerTrack, sheave_travel_m):
    """Roller centre radial shift and contact slope (Sorge eqs. 20b,c).

    Solves

    .. math:: (r_{c,min} + \\Delta r_c - r_{t0})^2
              + (\\Delta r_c \\cot\\beta_f - z_{t0} - \\Delta z)^2 = r_t^2

    for ``dr_c`` (a quadratic), on the branch that passes through
    ``dr_c = 0`` at ``dz = 0``, then

    .. math:: \\tan\\beta_s = \\frac{\\Delta r_c \\cot\\beta_f - z_{t0} - \\Delta z}
                                  {r_{c,min} + \\Delta r_c - r_{t0}}

    Returns
    -------
    delta_radius_m, beta_s_rad : ndarray
    """
    dz = np.asarray(sheave_travel_m, dtype=float)
    cot_f = 1.0 / math.tan(math.radians(roller.fixed_ramp_angle_deg))
    A = roller.roller_radius_min_m - roller.track_centre_radius_m
    qa = 1.0 + cot_f ** 2

    def roots(B):
        qb = 2.0 * (A + cot_f * B)
        qc = A ** 2 + B ** 2 - roller.track_radius_m ** 2
        disc = np.sqrt(np.maximum(qb ** 2 - 4.0 * qa * qc, 0.0))
        return (-qb + disc) / (2.0 * qa), (-qb - disc) / (2.0 * qa)

    plus0, minus0 = roots(-roller.track_centre_axial_m)
    use_plus = abs(plus0) <= abs(minus0)
    plus, minus = roots(-roller.track_centre_axial_m - dz)
    dr = plus if use_plus else minus
    num = dr * cot_f - roller.track_centre_axial_m - dz
    den = roller.roller_radius_min_m + dr - roller.track_centre_radius_m
    return dr, np.arctan2(num, den)


def roller_track_force_n(roller: RollerTrack, speed_rpm, sheave_travel_m):
    """Axial thrust of the roller-on-track actuator (Sorge eq. 21).

    .. math:: F_{z,R} \\cong \\frac{m_c\\, \\omega^2 (r_{c,min} + \\Delta r_c)}
                                  {\\cot\\beta_f + \\cot\\beta_s}
    """
    omega = np.asarray(speed_rpm, dtype=float) * RPM_TO_RAD_S
    dr, beta_s = roller_position(roller, sheave_travel_m)
    cot_f = 1.0 / math.tan(math.radians(roller.fixed_ramp_angle_deg))
    return roller.total_mass_kg * omega ** 2 * (roller.roller_radius_min_m + dr) / (cot_f + 1.0 / np.tan(beta_s))


def primary_centrifugal_force_n(tune: Tune, speed_rpm, primary_radius_m):
    """Flyweight (or roller) axial force alone, before the spring."""
    z = primary_sheave_travel_m(tune, primary_radius_m)
    if tune.primary_actuator == "roller_track":
        return roller_track_force_n(tune.roller_track, speed_rpm, z)
    return sliding_mass_force_n(tune.flyweights, speed_rpm, z)


def primary_spring_force_n(tune: Tune, primary_radius_m):
    """Primary spring force ``F_0 + k z_p`` (Messick eq. 9.3's bracket)."""
    s = tune.primary_spring
    return s.preload_n + s.rate_n_per_m * primary_sheave_travel_m(tune, primary_radius_m)


def primary_axial_force_n(tune: Tune, speed_rpm, primary_radius_m):
    """Net primary clamping force on the belt (Messick eq. 9.3).

    .. math:: F_p = F_{fly}(\\omega, z_p) - (F_0 + k z_p),
              \\quad z_p = 2\\tan\\alpha\\,(r_p - r_{p,min})

    Parameters
    ----------
    tune : Tune
    speed_rpm : float or array
        Primary (engine) speed.
    primary_radius_m : float or array
        Belt pitch radius on the primary; clipped to the travel range.

    Returns
    -------
    ndarray or float
        Axial force [N]; negative means the spring holds the sheave open
        (below engagement).
    """
    out = primary_centrifugal_force_n(tune, speed_rpm, primary_radius_m) - primary_spring_force_n(tune, primary_radius_m)
    return out if np.ndim(out) else float(out)


def primary_speed_for_force_rpm(tune: Tune, axial_force_n, primary_radius_m):
    """Inverse of :func:`primary_axial_force_n` in speed (force is ``c w^2``).

    Returns NaN where the actuator geometry gives no centrifugal force.
    """
    per_rpm2 = primary_centrifugal_force_n(tune, 1.0, primary_radius_m)
    need = np.asarray(axial_force_n, dtype=float) + primary_spring_force_n(tune, primary_radius_m)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.sqrt(np.where(per_rpm2 > 0, need / per_rpm2, np.nan))
    return out if np.ndim(out) else float(out)


# ---------------------------------------------------------------- secondary


def torque_fraction_sliding(split: TorqueSplit, torque_nm, axial_force_n, radius_m, tan_alpha_: float,
                            closing: bool | None, shift_speed_ratio: float = 0.0,
                            belt_exit_strain: float = 1e-3):
    """Share of the driven torque carried by the sliding half (Sorge eq. 11).

    .. math:: \\frac{M_s}{M} \\approx \\frac12 - \\left(a\\frac{\\rho}{\\varepsilon_{out}} + b\\right)
              \\left(\\frac{2 r F_z \\tan\\alpha}{M} - \\frac{\\sin\\alpha}{f}\\right)^{3/2}
              \\operatorname{sgn}\\rho

    ``closing`` picks the (a, b) pair and the sign of rho: ``True`` for the
    closing (down-shift) phase, ``False`` for opening (up-shift), ``None``
    for true steady state (rho = 0, equal split).  ``shift_speed_ratio`` is
    |rho| (Sorge: of order 1e-3 or less); at 0 only the ``b`` term remains,
    which is the quasi-static limit rho -> 0+/-.  The bracket is clipped at
    0 (gross-slip end of Fig. 8) and the result to
    [TORQUE_FRACTION_MIN, TORQUE_FRACTION_MAX].
    """
    if closing is None:
        return np.full(np.broadcast(np.asarray(torque_nm), np.asarray(axial_force_n)).shape, 0.5)[()]
    alpha = math.atan(tan_alpha_)
    M = np.maximum(np.abs(np.asarray(torque_nm, dtype=float)), 1e-9)
    x = np.maximum(2.0 * radius_m * np.asarray(axial_force_n, dtype=float) * tan_alpha_ / M
                   - math.sin(alpha) / split.friction_coefficient, 0.0)
    rho = abs(shift_speed_ratio) * (1.0 if closing else -1.0)
    a, b = (split.a_closing, split.b_closing) if closing else (split.a_opening, split.b_opening)
    sgn = 1.0 if closing else -1.0
    frac = 0.5 - (a * rho / belt_exit_strain + b) * x ** 1.5 * sgn
    return np.clip(frac, TORQUE_FRACTION_MIN, TORQUE_FRACTION_MAX)[()]


def secondary_spring_force_n(tune: Tune, secondary_radius_m_):
    """Axial spring part of eq. 22: ``F_z0 + K (-2 dr_N tan alpha)``."""
    s = tune.secondary_spring
    return s.preload_n + s.rate_n_per_m * secondary_sheave_travel_m(tune, secondary_radius_m_)


def secondary_torsion_torque_nm(tune: Tune, secondary_radius_m_):
    """Torsion-spring torque on the helix.

    Opening the sheave by ``z_s`` turns it ``z_s tan(delta) / r_h`` against
    the helix (the kinematics behind Sorge's ``omega_s - omega_f``), winding
    the torsion spring further.
    """
    s = tune.secondary_spring
    tan_d = math.tan(math.radians(tune.helix.angle_from_axis_deg))
    twist_rad = secondary_sheave_travel_m(tune, secondary_radius_m_) * tan_d / tune.helix.radius_m
    return s.torsion_preload_nm + s.torsion_rate_nm_per_rad * twist_rad


def _helix_force_n(tune: Tune, helix_torque_nm):
    # The helix rollers only push one way: if belt torque reverses past the
    # torsion preload they lift off and the helix carries nothing.
    tan_d = math.tan(math.radians(tune.helix.angle_from_axis_deg))
    return np.maximum(helix_torque_nm, 0.0) * tan_d / tune.helix.radius_m


def secondary_axial_force_n(tune: Tune, torque_secondary_nm, secondary_radius_m_, closing: bool | None = None,
                            shift_speed_ratio: float = 0.0, belt_exit_strain: float = 1e-3):
    """Secondary clamping force: springs plus helix feedback (Sorge eq. 22).

    .. math:: F_{zN} = F_{z0} + K z_s + \\frac{2 (M_{N,s} + M_t)}{d}\\tan\\delta,
              \\qquad M_{N,s} = \\frac{M_s}{M}(F_{zN})\\, M

    with ``d = 2 r_h`` and ``M_t`` the torsion-spring torque.  Because the
    share ``M_s/M`` of eq. 11 depends on ``F_zN`` itself, the opening and
    closing cases are solved for ``F_zN`` with Brent's method; at steady
    state (``closing=None``) the share is 1/2 and the result is explicit.

    Parameters
    ----------
    torque_secondary_nm : float or array
        Belt torque delivered to the secondary (positive when driving).
    secondary_radius_m_ : float or array
        Belt pitch radius on the secondary.
    closing : bool or None
        Shift phase for eq. 11 (see :func:`torque_fraction_sliding`).

    Returns
    -------
    ndarray or float
        Axial force [N].
    """
    M, rs = np.broadcast_arrays(np.asarray(torque_secondary_nm, dtype=float),
                                np.asarray(secondary_radius_m_, dtype=float))
    f_spring = secondary_spring_force_n(tune, rs)
    m_tors = secondary_torsion_torque_nm(tune, rs)
    if closing is None:
        out = f_spring + _helix_force_n(tune, 0.5 * M + m_tors)
        return out if out.ndim else float(out)

    ta = tan_alpha(tune)
    out = np.empty(M.shape)
    for idx in np.ndindex(M.shape):
        m, r, fs, mt = float(M[idx]), float(rs[idx]), float(f_spring[idx]), float(m_tors[idx])

        def resid(f):
            frac = torque_fraction_sliding(tune.torque_split, m, f, r, ta, closing,
                                           shift_speed_ratio, belt_exit_strain)
            return f - fs - float(_helix_force_n(tune, frac * m + mt))

        m_lo, m_hi = sorted((TORQUE_FRACTION_MIN * m, TORQUE_FRACTION_MAX * m))
        lo = fs + float(_helix_force_n(tune, m_lo + mt))
        hi = fs + float(_helix_force_n(tune, m_hi + mt))
        if hi - lo < 1e-9:
            out[idx] = lo
        else:
            out[idx] = brentq(resid, lo - 1e-9, hi + 1e-9, xtol=1e-9)
    return out if out.ndim else float(out)
