"""Open-belt drive geometry used by the actuators and the shift curve.

Pure numpy functions; radii and lengths in metres, angles in radians.
"""

from __future__ import annotations

import math

import numpy as np

from dyno.errors import DidNotConverge


def open_belt_length_m(primary_radius_m, secondary_radius_m, centre_distance_m):
    """Pitch length of an open belt on two pulleys.

    Notes
    -----
    With ``theta = asin((r_p - r_s) / C)`` (the span tilt),

    .. math:: L = 2 C \\cos\\theta + \\pi (r_p + r_s) + 2 \\theta (r_p - r_s)

    which is even in ``r_p - r_s`` so either pulley may be the larger.
    """
    rp = np.asarray(primary_radius_m, dtype=float)
    rs = np.asarray(secondary_radius_m, dtype=float)
    theta = np.arcsin(np.clip((rp - rs) / centre_distance_m, -1.0, 1.0))
    return 2.0 * centre_distance_m * np.cos(theta) + np.pi * (rp + rs) + 2.0 * theta * (rp - rs)


def wrap_angles_rad(primary_radius_m, secondary_radius_m, centre_distance_m):
    """Wrap angles ``(phi_p, phi_s) = (pi + 2 theta, pi - 2 theta)``."""
    rp = np.asarray(primary_radius_m, dtype=float)
    rs = np.asarray(secondary_radius_m, dtype=float)
    theta = np.arcsin(np.clip((rp - rs) / centre_distance_m, -1.0, 1.0))
    return np.pi + 2.0 * theta, np.pi - 2.0 * theta


def secondary_radius_for_primary_m(primary_radius_m, belt_pitch_length_m, centre_distance_m):
    """Secondary pitch radius that keeps the belt length fixed.

    Solved by vectorised Newton iteration; ``dL/dr_s = pi - 2 theta`` is
    always positive, so the root is unique and Newton converges in a few
    steps from the equal-radius guess.
    """
    rp = np.asarray(primary_radius_m, dtype=float)
    C = float(centre_distance_m)
    L = float(belt_pitch_length_m)
    rs = np.maximum((L - 2.0 * C) / np.pi - rp, 1e-6) * np.ones_like(rp)
    for _ in range(50):
        theta = np.arcsin(np.clip((rp - rs) / C, -1.0, 1.0))
        resid = open_belt_length_m(rp, rs, C) - L
        step = resid / (np.pi - 2.0 * theta)
        rs = rs - step
        if np.all(np.abs(step) < 1e-12):
            break
    else:  # pragma: no cover - dL/dr_s > 0 makes this unreachable for sane input
        raise DidNotConverge(f"secondary radius for L={L} C={C}")
    if np.any(rs <= 0):
        raise DidNotConverge(f"belt L={L} m too short for primary radius {rp.max()} m at C={C} m")
    return rs if rs.ndim else float(rs)


def primary_radius_for_ratio_m(ratio, belt_pitch_length_m, centre_distance_m):
    """Primary pitch radius giving geometric ratio ``r_s / r_p`` (scalar)."""
    from scipy.optimize import brentq

    L, C = float(belt_pitch_length_m), float(centre_distance_m)
    hi = (L - 2.0 * C) / math.pi  # r_s -> 0 limit
    f = lambda rp: secondary_radius_for_primary_m(rp, L, C) / rp - ratio  # noqa: E731
    return brentq(f, 1e-5, hi * 0.999, xtol=1e-12)
