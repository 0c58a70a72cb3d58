"""AR-CVT actuation model (van Kerkhoven 2006, TU/e DCT 2006.077).

An Axial-Radial CVT: the output ("axial") pulley changes its radius ``R_a``
by moving flanges; the input ("radial") pulley of fixed radius ``R_r`` sits
on a lever and moves so that the centre distance ``a_h`` takes up the fixed
push-belt length.  Equation numbers are the report's.

Pure functions on an :class:`ArcvtParams`; :func:`load_trace` is the only
file reader.  Lengths in metres, forces in newtons, torques N m.
"""

from __future__ import annotations

import csv
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import brentq

from dyno.errors import ConfigError, DidNotConverge


@dataclass(frozen=True)
class ArcvtParams:
    """Report Tables 3.1-3.3 (defaults) plus the drive-line speeds.

    ``belt_length_m`` is not printed in the report; the default follows
    from Table 3.1: at ``R_a = R_r`` the wrap is pi and eq. 3.1 gives
    ``L = 2 a_h,max + 2 pi R_r`` = 0.7465 m.
    """

    radial_radius_m: float = 0.030  # R_r
    axial_radius_min_m: float = 0.030  # R_a,min
    axial_radius_max_m: float = 0.101  # R_a,max
    belt_length_m: float = 2 * 0.279 + 2 * math.pi * 0.030
    wedge_half_angle_deg: float = 11.0  # theta
    clamp_force_n: float = 20e3  # F_clamp
    load_torque_nm: float = 96.0  # T_a
    input_gear_radius_m: float = 0.030  # R_i (r_i)
    arm_length_m: float = 0.100  # L_arm
    pivot_distance_m: float = 0.200  # a_act
    output_speed_rpm: float = 3000.0
    pre_ratio: float = 6.0  # radial-pulley speed / engine speed (den Ouden's pre-reduction)
    vertical_force_form: str = "printed"  # eq. 3.12/3.13 as printed, or "integral"
    horizontal_force_model: str = "simplified"  # eq. 3.13, or "vroemen" (eq. 3.24)

    def __post_init__(self):
        for k, v in asdict(self).items():
            if isinstance(v, float) and not (math.isfinite(v) and v > 0):
                raise ConfigError("<arcvt params>", k, f"a finite positive number, got {v!r}")
        if self.vertical_force_form not in ("printed", "integral"):
            raise ConfigError("<arcvt params>", "vertical_force_form", "'printed' or 'integral'")
        if self.horizontal_force_model not in ("simplified", "vroemen"):
            raise ConfigError("<arcvt params>", "horizontal_force_model", "'simplified' or 'vroemen'")


# ------------------------------------------------------------------ geometry


def wrap_radial_rad(axial_radius_m, centre_distance_m, radial_radius_m):
    """Eq. 3.2: ``beta_r = 2 acos((R_a - R_r) / a_h)``."""
    return 2.0 * np.arccos((np.asarray(axial_radius_m) - radial_radius_m) / np.asarray(centre_distance_m))


def belt_length_residual_m(centre_distance_m, axial_radius_m, p: ArcvtParams):
    """Eq. 3.3 rearranged to ``f(a_h, R_a) = 0`` (belt length minus L)."""
    a, ra, rr = centre_distance_m, axial_radius_m, p.radial_radius_m
    beta = wrap_radial_rad(ra, a, rr)
    return 2.0 * a * np.sin(beta / 2) + rr * beta + ra * (2 * np.pi - beta) - p.belt_length_m


def centre_distance_m(axial_radius_m: float, p: ArcvtParams) -> float:
    """Centre distance ``a_h`` for an axial-pulley radius (eq. 3.3, Brent).

    The belt length grows monotonically with ``a_h`` at fixed radii, so the
    root is unique on ``(|R_a - R_r|, L/2)``.
    """
    ra = float(axial_radius_m)
    lo = abs(ra - p.radial_radius_m) * (1 + 1e-12) + 1e-12
    hi = p.belt_length_m / 2
    f = lambda a: float(belt_length_residual_m(a, ra, p))  # noqa: E731
    if f(lo) > 0 or f(hi) < 0:
        raise DidNotConverge(f"AR-CVT: no centre distance for R_a={ra} m with L={p.belt_length_m} m")
    return brentq(f, lo, hi, xtol=1e-13)


def centre_distance_slope(axial_radius_m: float, p: ArcvtParams) -> float:
    """``d a_h / d R_a`` (eq. 3.4's partial), exact by implicit differentiation.

    With ``L(a, R_a) = 2 a sin(b/2) + R_r b + R_a (2 pi - b)``,
    ``dL/da = 2 sin(b/2)`` and ``dL/dR_a = 2 pi - b`` (the ``b``-terms
    cancel, the belt being tangent), so ``da/dR_a = -(2 pi - b)/(2 sin(b/2))``.
    """
    a = centre_distance_m(axial_radius_m, p)
    b = float(wrap_radial_rad(axial_radius_m, a, p.radial_radius_m))
    return -(2 * math.pi - b) / (2 * math.sin(b / 2))


def quadratic_fit(p: ArcvtParams, n: int = 50) -> tuple[np.ndarray, float]:
    """Eq. 3.5: least-squares ``a_h = p0 + p1 R_a + p2 R_a^2`` over the range;
    returns ``(coeffs [p0, p1, p2], max |error| m)`` (the report: 4e-4 m)."""
    ra = np.linspace(p.axial_radius_min_m, p.axial_radius_max_m, n)
    ah = np.array([centre_distance_m(r, p) for r in ra])
    coef = np.polynomial.polynomial.polyfit(ra, ah, 2)
    err = np.abs(np.polynomial.polynomial.polyval(ra, coef) - ah).max()
    return coef, float(err)


def geometry_extremes(p: ArcvtParams) -> dict[str, float]:
    """Table 3.1: the centre-distance extremes over the R_a range."""
    a_max = centre_distance_m(p.axial_radius_min_m, p)
    a_min = centre_distance_m(p.axial_radius_max_m, p)
    return {"axial_radius_min_m": p.axial_radius_min_m, "axial_radius_max_m": p.axial_radius_max_m,
            "centre_distance_min_m": a_min, "centre_distance_max_m": a_max,
            "radial_radius_m": p.radial_radius_m, "belt_length_m": p.belt_length_m}


# -------------------------------------------------------------------- forces


def belt_forces_n(axial_radius_m: float, p: ArcvtParams) -> tuple[float, float]:
    """``(F_hor, F_vert)`` on the radial pulley (eq. 3.13).

    .. math:: F_{hor} = 4\\tan\\theta\\,\\frac{F_{clamp}}{2\\pi - \\beta_r}\\sin\\tfrac{\\beta_r}{2},
              \\qquad F_{vert} = 2\\frac{Q}{\\beta_r}\\left(\\sin\\tfrac{\\beta_r}{2} - 1\\right),
              \\quad Q = T_a / R_a

    The ``- 1`` is as printed; the integral of eq. 3.12 it stands for
    evaluates to ``sin(beta_r/2)`` alone (``vertical_force_form="integral"``).
    ``horizontal_force_model="vroemen"`` replaces F_hor by the report's
    eq. 3.24, ``6.1e3 + 1.3e4 R_a`` (R_a in m), used from its Fig. 3.10 on.
    """
    a = centre_distance_m(axial_radius_m, p)
    beta = float(wrap_radial_rad(axial_radius_m, a, p.radial_radius_m))
    tan_t = math.tan(math.radians(p.wedge_half_angle_deg))
    if p.horizontal_force_model == "vroemen":
        f_hor = 6.1e3 + 1.3e4 * axial_radius_m
    else:
        f_hor = 4 * tan_t * p.clamp_force_n / (2 * math.pi - beta) * math.sin(beta / 2)
    q = p.load_torque_nm / axial_radius_m
    bracket = math.sin(beta / 2) - (1.0 if p.vertical_force_form == "printed" else 0.0)
    return f_hor, 2 * q / beta * bracket


def arm_angle_rad(centre_distance_m_: float, p: ArcvtParams) -> float:
    """Eq. 3.16: ``alpha = asin((a_act^2 - a_h^2 - L_arm^2) / (-2 a_h L_arm))``."""
    s = (p.pivot_distance_m ** 2 - centre_distance_m_ ** 2 - p.arm_length_m ** 2) / (
        -2 * centre_distance_m_ * p.arm_length_m)
    if abs(s) > 1:
        raise DidNotConverge(f"AR-CVT: arm of {p.arm_length_m} m cannot reach a_h={centre_distance_m_:.4f} m "
                             f"from a pivot {p.pivot_distance_m} m away")
    return math.asin(s)


def actuation(axial_radius_m: float, p: ArcvtParams, clockwise: bool = True) -> dict[str, float]:
    """Actuation force and torque at one radius (eqs. 3.17-3.19).

    Clockwise: ``F_act = cos(a) F_hor - T_i/r_i + sin(a) F_vert``;
    counter-clockwise: ``F_act = cos(a) F_hor + T_i/r_i - sin(a) F_vert``;
    ``T_act = F_act L_arm``.  The input torque on the radial pulley is the
    load torque scaled by the radii (lossless), ``T_i = T_a R_r / R_a``.
    """
    a = centre_distance_m(axial_radius_m, p)
    alpha = arm_angle_rad(a, p)
    f_hor, f_vert = belt_forces_n(axial_radius_m, p)
    t_i = p.load_torque_nm * p.radial_radius_m / axial_radius_m
    sign = 1.0 if clockwise else -1.0
    f_act = math.cos(alpha) * f_hor - sign * t_i / p.input_gear_radius_m + sign * math.sin(alpha) * f_vert
    return {"axial_radius_m": axial_radius_m, "centre_distance_m": a, "alpha_rad": alpha,
            "force_horizontal_n": f_hor, "force_vertical_n": f_vert, "input_torque_nm": t_i,
            "actuation_force_n": f_act, "actuation_torque_nm": f_act * p.arm_length_m,
            "centre_distance_slope": centre_distance_slope(axial_radius_m, p)}


def actuation_table(p: ArcvtParams, n: int = 15) -> list[dict[str, float]]:
    """Both rotation directions over the R_a range (the report's Fig. 3.8)."""
    rows = []
    for ra in np.linspace(p.axial_radius_min_m, p.axial_radius_max_m, n):
        cw, ccw = actuation(float(ra), p, True), actuation(float(ra), p, False)
        rows.append({**cw, "actuation_force_ccw_n": ccw["actuation_force_n"],
                     "actuation_torque_ccw_nm": ccw["actuation_torque_nm"]})
    return rows


# ------------------------------------------------------------------- trace


def axial_radius_for_engine_m(engine_rpm, p: ArcvtParams):
    """Radius that keeps the output at ``output_speed_rpm``:
    ``R_a = R_r n_radial / n_out`` with ``n_radial = pre_ratio n_engine``,
    clipped to the pulley range (outside it the output speed drifts)."""
    ra = p.radial_radius_m * p.pre_ratio * np.asarray(engine_rpm, dtype=float) / p.output_speed_rpm
    return np.clip(ra, p.axial_radius_min_m, p.axial_radius_max_m)


def evaluate_trace(time_s, engine_rpm, p: ArcvtParams, clockwise: bool = True) -> dict[str, Any]:
    """Shift rate and actuation power over an engine-speed trace (Ch. 4).

    ``R_a`` follows the engine speed; the shift rate is the backward
    difference of eq. 4.1 (with the trace's own time steps);
    ``a_h' = (da_h/dR_a) R_a'`` (eq. 3.4), ``v_act = a_h'/cos(alpha)``
    (eq. 3.21) and ``P_act = F_act v_act`` (eqs. 3.22/3.23).  As in the
    report, negative power (the belt drives the arm back) is reported but
    excluded from the maximum demand.
    """
    t = np.asarray(time_s, dtype=float)
    n = np.asarray(engine_rpm, dtype=float)
    if t.ndim != 1 or t.size < 2 or t.shape != n.shape or np.any(np.diff(t) <= 0):
        raise ConfigError("<trace>", "time_s", "at least 2 samples with strictly increasing time")
    ra = axial_radius_for_engine_m(n, p)
    rate = np.r_[0.0, np.diff(ra) / np.diff(t)]
    power = np.empty_like(ra)
    force = np.empty_like(ra)
    torque = np.empty_like(ra)
    a_rate = np.empty_like(ra)
    w_arm = np.empty_like(ra)
    cache: dict[float, dict[str, float]] = {}
    for k, r in enumerate(ra):
        key = round(float(r), 9)
        act = cache.get(key) or cache.setdefault(key, actuation(float(r), p, clockwise))
        a_rate[k] = act["centre_distance_slope"] * rate[k]
        v_act = a_rate[k] / math.cos(act["alpha_rad"])
        force[k] = act["actuation_force_n"]
        torque[k] = act["actuation_torque_nm"]
        power[k] = force[k] * v_act
        w_arm[k] = v_act / p.arm_length_m
    return {
        "time_s": t.tolist(), "engine_rpm": n.tolist(), "axial_radius_m": ra.tolist(),
        "shift_rate_m_s": rate.tolist(), "centre_distance_rate_m_s": a_rate.tolist(),
        "actuation_force_n": force.tolist(), "actuation_torque_nm": torque.tolist(),
        "actuation_power_w": power.tolist(),
        "max_abs_shift_rate_m_s": float(np.abs(rate).max()),
        "max_actuation_power_w": float(max(power.max(), 0.0)),
        "max_abs_actuation_torque_nm": float(np.abs(torque).max()),
        "max_arm_speed_rad_s": float(np.abs(w_arm).max()),
        "energy_positive_j": float(np.sum(np.clip(power[1:], 0, None) * np.diff(t))),
    }


def load_trace(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Engine-speed trace CSV with columns ``time_s, engine_rpm`` (a header
    row naming them; ``#`` comments allowed)."""
    path = Path(path)
    try:
        lines = [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip() and not ln.startswith("#")]
    except OSError as exc:
        raise ConfigError(path, "<file>", f"a readable trace ({exc.strerror})") from None
    rows = list(csv.reader(lines))
    if not rows:
        raise ConfigError(path, "<rows>", "a header and samples")
    header = [h.strip().lower() for h in rows[0]]
    for col in ("time_s", "engine_rpm"):
        if col not in header:
            raise ConfigError(path, col, "a column of that name")
    it, ie = header.index("time_s"), header.index("engine_rpm")
    try:
        data = np.array([[float(r[it]), float(r[ie])] for r in rows[1:]])
    except (ValueError, IndexError):
        raise ConfigError(path, "<rows>", "numbers in time_s and engine_rpm") from None
    if data.shape[0] < 2:
        raise ConfigError(path, "<rows>", "at least 2 samples")
    return data[:, 0], data[:, 1]


def params_from_dict(data: dict, path: str = "<arcvt params>") -> ArcvtParams:
    """Override the defaults from a mapping (e.g. a TOML table)."""
    fields = ArcvtParams.__dataclass_fields__
    kwargs = {}
    for k, v in data.items():
        if k not in fields:
            raise ConfigError(path, k, f"unknown key (allowed: {', '.join(fields)})")
        kwargs[k] = float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v
    try:
        return replace(ArcvtParams(), **kwargs)
    except ConfigError as exc:
        raise ConfigError(path, exc.field, exc.expected) from None
