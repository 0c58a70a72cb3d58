"""Open-belt geometry: pitch length <-> radii <-> centre distance, wrap angles.

All relations assume the belt runs on its nominal (pitch) radii with straight
spans tangent to both pulleys (thesis Section 6.2.1, Fig. 6.19):

    sin(theta_T) = (R_S - R_P) / L_c                                (6.10)
    Phi_P = pi - 2 theta_T,  Phi_S = pi + 2 theta_T                  (6.11)
    L_p = R_P Phi_P + R_S Phi_S + 2 L_c cos(theta_T)                 (6.12)

For a variable centre distance (AR-CVT, van Kerkhoven 2006 eqs 3.1-3.3) the
same closed curve is solved for the centre distance a_h with both radii given;
with beta_r = 2 acos((R_a - R_r)/a_h) the wrap on the fixed-radius pulley,

    a_h = (L - R_r beta_r - R_a (2 pi - beta_r)) / (2 sin(beta_r / 2)).

No closed form exists for the inverse problems, so every solver below
brackets the root first (the belt length is monotonic in the unknown) and
calls :func:`scipy.optimize.brentq`; outside the feasible range it raises a
:class:`~dyno.errors.ConfigError` that says what the range is.
"""

from __future__ import annotations

import math

from scipy.optimize import brentq

from dyno.model.params import bad_input

_XTOL_M = 1e-13


def tangent_angle_rad(r_primary_m: float, r_secondary_m: float, centre_distance_m: float) -> float:
    """theta_T of eq 6.10 (positive when the secondary is the larger pulley)."""
    s = (r_secondary_m - r_primary_m) / centre_distance_m
    if not -1.0 < s < 1.0:
        raise bad_input(
            "radii",
            f"|R_S - R_P| < centre distance ({centre_distance_m:g} m), got R_P={r_primary_m:g} m, R_S={r_secondary_m:g} m",
        )
    return math.asin(s)


def wrap_angles_rad(r_primary_m: float, r_secondary_m: float, centre_distance_m: float) -> tuple[float, float]:
    """Geometric (string) wrap angles (Phi_P, Phi_S) of eq 6.11."""
    t = tangent_angle_rad(r_primary_m, r_secondary_m, centre_distance_m)
    return math.pi - 2.0 * t, math.pi + 2.0 * t


def belt_length_m(r_primary_m: float, r_secondary_m: float, centre_distance_m: float) -> float:
    """Pitch length of the open belt on the given radii (eq 6.12)."""
    t = tangent_angle_rad(r_primary_m, r_secondary_m, centre_distance_m)
    return (
        r_primary_m * (math.pi - 2.0 * t)
        + r_secondary_m * (math.pi + 2.0 * t)
        + 2.0 * centre_distance_m * math.cos(t)
    )


def equal_radius_m(pitch_length_m: float, centre_distance_m: float) -> float:
    """Radius at the 1:1 ratio (eq 6.1)."""
    r = (pitch_length_m - 2.0 * centre_distance_m) / (2.0 * math.pi)
    if r <= 0:
        raise bad_input("pitch_length_m", f"longer than twice the centre distance ({2 * centre_distance_m:g} m)")
    return r


def _solve_monotone(f, lo: float, hi: float, what: str, expected: str) -> float:
    """Root of an increasing ``f`` on [lo, hi], or a ConfigError naming the range."""
    flo, fhi = f(lo), f(hi)
    if flo > 0 or fhi < 0:
        raise bad_input(what, expected)
    if flo == 0:
        return lo
    if fhi == 0:
        return hi
    return brentq(f, lo, hi, xtol=_XTOL_M, rtol=1e-15, maxiter=200)


def primary_radius_m(r_secondary_m: float, pitch_length_m: float, centre_distance_m: float) -> float:
    """R_P for a given R_S on a fixed-centre drive (Appendix B, first function)."""
    lo = max(1e-9, r_secondary_m - centre_distance_m * (1 - 1e-12))
    hi = r_secondary_m + centre_distance_m * (1 - 1e-12)
    return _solve_monotone(
        lambda r: belt_length_m(r, r_secondary_m, centre_distance_m) - pitch_length_m,
        lo,
        hi,
        "secondary_radius_m",
        f"a radius for which a primary radius fits the {pitch_length_m:g} m belt at {centre_distance_m:g} m centres",
    )


def secondary_radius_m(r_primary_m: float, pitch_length_m: float, centre_distance_m: float) -> float:
    """R_S for a given R_P on a fixed-centre drive."""
    lo = max(1e-9, r_primary_m - centre_distance_m * (1 - 1e-12))
    hi = r_primary_m + centre_distance_m * (1 - 1e-12)
    return _solve_monotone(
        lambda r: belt_length_m(r_primary_m, r, centre_distance_m) - pitch_length_m,
        lo,
        hi,
        "primary_radius_m",
        f"a radius for which a secondary radius fits the {pitch_length_m:g} m belt at {centre_distance_m:g} m centres",
    )


def ratio_limits(pitch_length_m: float, centre_distance_m: float) -> tuple[float, float]:
    """Open interval of geometric ratios R_S/R_P that fit the belt at all.

    The extremes are reached as one radius goes to zero; a real drive is far
    narrower (sheave diameters), which the caller must check.
    """
    r_max = secondary_radius_m(1e-9, pitch_length_m, centre_distance_m)
    return 1e-9 / r_max, r_max / 1e-9


def radii_for_ratio(ratio: float, pitch_length_m: float, centre_distance_m: float) -> tuple[float, float]:
    """(R_P, R_S) with R_S/R_P = ``ratio`` on a fixed-centre drive (Appendix B, second function)."""
    if not (math.isfinite(ratio) and ratio > 0):
        raise bad_input("ratio", f"a finite positive R_S/R_P, got {ratio!r}")
    equal_radius_m(pitch_length_m, centre_distance_m)  # checks the belt is long enough at all
    # Feasibility of the tangent angle: |ratio - 1| R_P < L_c.
    hi = pitch_length_m / (math.pi * (1.0 + ratio))
    if ratio != 1.0:
        hi = min(hi, centre_distance_m / abs(ratio - 1.0) * (1 - 1e-12))

    def excess(r_p):
        return belt_length_m(r_p, ratio * r_p, centre_distance_m) - pitch_length_m

    r_p = _solve_monotone(
        excess,
        1e-12,
        hi,
        "ratio",
        f"a ratio R_S/R_P the {pitch_length_m:g} m belt can take at {centre_distance_m:g} m centres, got {ratio:g}",
    )
    return r_p, ratio * r_p


# --- variable centre distance (AR-CVT, van Kerkhoven 2006 eqs 3.1-3.3) -------------------------


def centre_distance_m(r_fixed_m: float, r_variable_m: float, belt_length_m_: float) -> float:
    """Centre distance a_h for given radii and belt length (eq 3.3, solved by bracketing).

    The belt length grows monotonically with a_h for fixed radii, between the
    touching limit a_h -> |R_a - R_r| and a_h = L/2.
    """
    dr = abs(r_variable_m - r_fixed_m)
    lo = max(dr * (1 + 1e-12), 1e-12)
    hi = belt_length_m_ / 2.0
    if hi <= lo:
        raise bad_input("belt_length_m", "longer than twice the radius difference")
    return _solve_monotone(
        lambda a: belt_length_m(r_fixed_m, r_variable_m, a) - belt_length_m_,
        lo,
        hi,
        "radii",
        f"radii R_r={r_fixed_m:g} m, R_a={r_variable_m:g} m that a {belt_length_m_:g} m belt can wrap",
    )


def arcvt_wrap_angle_rad(r_fixed_m: float, r_variable_m: float, centre_distance_m_: float) -> float:
    """Wrap on the fixed-radius (radial) pulley, beta_r = 2 acos((R_a - R_r)/a_h) (eq 3.2)."""
    c = (r_variable_m - r_fixed_m) / centre_distance_m_
    if not -1.0 < c < 1.0:
        raise bad_input("centre_distance_m", "larger than the radius difference")
    return 2.0 * math.acos(c)


def arcvt_centre_distance_residual_m(a_h_m: float, r_fixed_m: float, r_variable_m: float, belt_length_m_: float) -> float:
    """Residual of eq 3.1 written as in the report (used to cross-check :func:`centre_distance_m`)."""
    beta_r = arcvt_wrap_angle_rad(r_fixed_m, r_variable_m, a_h_m)
    rhs = (belt_length_m_ - r_fixed_m * beta_r - r_variable_m * (2 * math.pi - beta_r)) / (2 * math.sin(beta_r / 2))
    return a_h_m - rhs


def variable_radius_m(r_fixed_m: float, centre_distance_m_: float, belt_length_m_: float) -> float:
    """Radius R_a of the axially adjusted pulley for a given centre distance."""
    lo = max(1e-9, r_fixed_m - centre_distance_m_ * (1 - 1e-12))
    hi = r_fixed_m + centre_distance_m_ * (1 - 1e-12)
    return _solve_monotone(
        lambda r: belt_length_m(r_fixed_m, r, centre_distance_m_) - belt_length_m_,
        lo,
        hi,
        "centre_distance_m",
        f"a centre distance at which the {belt_length_m_:g} m belt fits the {r_fixed_m:g} m pulley",
    )
