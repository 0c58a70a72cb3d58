r"""Full steady model of the thesis: Kong-Parker contact with bending, both spans, BVP.

This ports Messick (2018) Sections 3 and 5 (equations, and the appendix code
where the errata in ``docs/belt-model.md`` say the code is right) to
:func:`scipy.integrate.solve_bvp`.  scipy is imported lazily, inside the
solver, so importing this module is cheap.

Regions and independent variable
--------------------------------
Four regions share one normalised coordinate :math:`t \in [0, 1]`, each
solved in the direction of belt travel (both pulleys turn counter-clockwise,
primary centre at the origin, secondary at :math:`(L_c, 0)`):

* primary contact (driver), :math:`\phi = \Phi_P t`, entered from the tight span;
* slack span, :math:`s = L_s t`, from the primary to the secondary;
* secondary contact (driven), :math:`\phi = \Phi_S t`;
* tight span, :math:`s = L_t t`, from the secondary back to the primary.

Contact equations (hat = derivative in t; T tractive tension, theta angle of
inclination, x radial penetration)
-----------------------------------------------------------------------------
Belt speed from the mass flow G (eqs 3.5-3.11)
:math:`V = G (T + EA) / (EA\,m_o - G^2)`; sliding velocity components
:math:`v_r = V \sin\theta`, :math:`v_c = V\cos\theta - (R - x)\omega` (3.12);
sliding angle :math:`\cos\gamma = v_r/|v|`, :math:`\sin\gamma = v_c/|v|` (3.13);
apparent sheave angle :math:`\tan\beta_s = \tan\beta\cos\gamma` (3.14);
sheave pressure :math:`p = k x / (2(\cos\beta + \mu\sin\beta_s))` (3.18);
viscous-Coulomb friction :math:`\mu = \mu_0 \min(1, |v|/v_{th})` (Fig. 3.6).

With :math:`Q = -EI\hat\theta''/(R^2\Phi^2) + EI\hat x'/(R^3\Phi)` (3.38) and
:math:`\hat x'' = \Phi(\hat x'\tan\theta - (R-x)\hat\theta'\sec^2\theta)` (3.42):

.. math::

    \hat T' &= 2\Phi p(R-x)\,[-\sin\beta\tan\theta
              + \mu\cos\beta_s(\tan\theta\cos\gamma + \sin\gamma)] + (\hat\theta' - \Phi) Q \\
    \hat\theta''' &= \frac{T R^3 \Phi^3}{EI (R + 2x)}\Big(\frac{\hat\theta'}{\Phi} - 1
              + \frac{2p}{T}(R-x)[\sin\beta - \mu\cos\beta_s(\cos\gamma - \sin\gamma\tan\theta)]
              + \frac{EI\,\hat x''}{T R^3 \Phi^2}\Big)

(eq 3.39/5.5 and eq 5.6 with the Q' sign of the appendix code, which the
errata show is the right one: tension then gives a decaying bending response).
Integrated torque and axial force (5.54, 5.60):
:math:`\hat M' = 2\Phi\mu p\cos\beta_s\sin\gamma (R-x)^2/\cos\theta`,
:math:`\hat A' = \Phi (k x / 2)(R - x)/\cos\theta`.

Span equations (Kong & Parker; thesis 3.45, 3.48, 5.13, 5.14)
-------------------------------------------------------------
:math:`\hat\tau' = -(EI/L^2)\hat\vartheta'\hat\vartheta''`,
:math:`\hat\vartheta''' = (L^2\tau/EI)\hat\vartheta'`,
:math:`\hat X' = \cos\vartheta`, :math:`\hat Y' = \sin\vartheta` (positions scaled by L).

Variant ``as_published`` keeps the appendix code's three errors: ``L^2`` and
``1/L^2`` swapped in both span equations (an effective span stiffness
EI L^4), the primary exit zero-shear condition using the entry value of
:math:`\hat x'`, and the zero-shear conditions without the factor Phi.

Unknown constants
-----------------
Eight ``p`` parameters of ``solve_bvp`` (faster than zero-derivative states):
secondary speed and mass flow as per-mille creeps about their ideal values,
the wrap angles :math:`\Phi_S, \Phi_P`, the orientation angles
:math:`C_S, C_P` (Fig. 5.1) and the span lengths :math:`L_t, L_s`.

Boundary conditions (34 = 26 states + 8 parameters)
---------------------------------------------------
Zero penetration at every contact end (5.51); eq 3.24 at each entry (5.52,
5.53); zero torque and axial force at the primary entry (5.61, 5.62);
continuity of tension (5.47-5.50), direction (5.35-5.38 with 5.21-5.24,
5.23 with :math:`-\theta_{S1}`), curvature (5.39-5.42) and position
(5.27-5.34, exit/entry labels as in the code); zero shear at the four contact
ends (5.43-5.46, :math:`-\hat\theta'' + \Phi\hat x'/R = 0`); and the
operating point: primary torque plus either the slack-span tractive tension
at the primary exit or the primary axial force.

Numerics
--------
Geometric initial guess (wrap angles and tangent points shortened by the
conventional arching deficit, straight spans, tension ramp, penetration
T/(k R tan beta) ramped to zero at both ends, theta from eq 3.24),
continuation on the slip threshold from 1 m/s down by a factor per step,
re-meshing to a few hundred nodes between steps (``solve_bvp`` only adds
nodes), warm starts with homotopy in the physical parameters.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from dataclasses import dataclass, field, fields, replace

import numpy as np

from dyno.errors import DidNotConverge, GrossSlip
from dyno.model import geometry
from dyno.model.params import VARIANTS, ModelParams, OperatingPoint, TABLE_6_1, TABLE_6_1_POINT, bad_input

# ---- state layout ---------------------------------------------------------------------------
# secondary contact
S_T, S_TH, S_TH1, S_TH2, S_X, S_X1 = range(0, 6)
# primary contact
P_T, P_TH, P_TH1, P_TH2, P_X, P_X1, P_M, P_A = range(6, 14)
# tight span (secondary exit -> primary entry) and slack span (primary exit -> secondary entry)
T_TAU, T_V, T_V1, T_V2, T_XP, T_YP = range(14, 20)
L_TAU, L_V, L_V1, L_V2, L_XP, L_YP = range(20, 26)
N_STATES = 26
# parameters
K_WS, K_PHIS, K_G, K_PHIP, K_CS, K_CP, K_LT, K_LS = range(8)
N_PARAMS = 8

# Scales: solve_bvp's tolerances are relative to 1 + |value|, so every state
# is kept O(1): a penetration of 1 mm held in metres would be "converged"
# with a 1 mm error.
TENSION_REF_N = 100.0
PENETRATION_REF_M = 1e-3
TORQUE_REF_NM = 10.0
AXIAL_REF_N = 100.0
POSITION_BC_REF_M = 1e-3  # position continuity residuals in mm
CREEP_SCALE = 1e-3  # speed and mass-flow unknowns are per-mille creeps
MIN_RADIUS_M = 0.01  # below this the belt (~7 mm thick) cannot bend round the pulley: outside the model


@dataclass(frozen=True)
class Case:
    """One numerical case: all the floats the ODEs and BCs need, in SI units."""

    r_primary_m: float
    r_secondary_m: float
    centre_distance_m: float
    ea_n: float
    ei_nm2: float
    k_n_m2: float
    mass_kg_m: float
    mu: float
    beta_rad: float
    omega_primary_rad_s: float
    torque_nm: float
    slack_tension_n: float  # used when bc == "slack_tension"
    axial_force_n: float  # used when bc == "primary_axial_force"
    slip_threshold_m_s: float
    variant: str = "corrected"
    bc: str = "slack_tension"
    friction_corner: float = 0.0  # 0: the thesis's sharp viscous-Coulomb corner; > 0: rounded (C-infinity)

    @property
    def g_ref(self) -> float:
        """Ideal mass flow: the belt at the primary's pitch speed, unstretched."""
        return self.mass_kg_m * self.omega_primary_rad_s * self.r_primary_m

    @property
    def omega_secondary_ref(self) -> float:
        return self.omega_primary_rad_s * self.r_primary_m / self.r_secondary_m

    def name(self) -> str:
        level = (
            f"T_slack={self.slack_tension_n:g} N" if self.bc == "slack_tension" else f"F_axial,P={self.axial_force_n:g} N"
        )
        return (
            f"[{self.variant}] R_S/R_P={self.r_secondary_m / self.r_primary_m:.4g} "
            f"({self.r_primary_m * 1e3:.2f}/{self.r_secondary_m * 1e3:.2f} mm), "
            f"{self.omega_primary_rad_s * 60 / (2 * math.pi):.0f} rpm, {self.torque_nm:g} N*m, {level}, "
            f"EI={self.ei_nm2:g} N*m^2, beta={math.degrees(self.beta_rad):g} deg, k={self.k_n_m2:.4g} N/m^2, "
            f"mu={self.mu:g}, v_th={self.slip_threshold_m_s:.3g} m/s"
        )


def make_case(
    params: ModelParams,
    op: OperatingPoint,
    variant: str = "corrected",
    slip_threshold_m_s: float = 1e-4,
) -> Case:
    if variant not in VARIANTS:
        raise bad_input("variant", f"one of {', '.join(VARIANTS)}, got {variant!r}")
    if not (math.isfinite(slip_threshold_m_s) and slip_threshold_m_s > 0):
        raise bad_input("slip_threshold_m_s", f"a positive speed, got {slip_threshold_m_s!r}")
    belt, drive = params.belt, params.drive
    r_p, r_s = geometry.radii_for_ratio(op.ratio, belt.pitch_length_m, drive.centre_distance_m)
    if min(r_p, r_s) < MIN_RADIUS_M:
        raise bad_input("ratio", f"a ratio whose radii are at least {MIN_RADIUS_M * 1e3:g} mm (got R_P={r_p * 1e3:.3g} mm, "
                                 f"R_S={r_s * 1e3:.3g} mm for R_S/R_P={op.ratio:g})")
    return Case(
        r_primary_m=r_p,
        r_secondary_m=r_s,
        centre_distance_m=drive.centre_distance_m,
        ea_n=belt.axial_stiffness_n,
        ei_nm2=belt.bending_stiffness_nm2,
        k_n_m2=belt.radial_stiffness_n_m2,
        mass_kg_m=belt.mass_per_length_kg_m,
        mu=belt.friction_coefficient,
        beta_rad=drive.sheave_half_angle_rad,
        omega_primary_rad_s=op.primary_speed_rad_s,
        torque_nm=op.primary_torque_nm,
        slack_tension_n=op.slack_tension_n if op.slack_tension_n is not None else float("nan"),
        axial_force_n=op.primary_axial_force_n if op.primary_axial_force_n is not None else float("nan"),
        slip_threshold_m_s=slip_threshold_m_s,
        variant=variant,
        bc=op.boundary_condition,
    )


# ---- physics --------------------------------------------------------------------------------


def contact_terms(case: Case, t_n, th, th1, th2, x_m, x1_m, radius_m, phi, omega, g):
    """Right-hand sides of one contact region, physical units.

    Returns ``(dT, dth3, dx2, dM, dA, extras)`` where derivatives are with
    respect to the normalised coordinate and ``extras`` holds the sliding
    speed, sliding angle, friction coefficient and pressure for output.
    """
    c, s = np.cos(th), np.sin(th)
    tn = s / c
    sec2 = 1.0 / (c * c)
    ea, m = case.ea_n, case.mass_kg_m
    v_belt = g * (t_n + ea) / (ea * m - g * g)
    r_loc = radius_m - x_m
    v_rad = v_belt * s
    v_circ = v_belt * c - r_loc * omega
    v_mag = np.sqrt(v_rad * v_rad + v_circ * v_circ) + 1e-300
    mu = case.mu * friction_shape(v_mag / case.slip_threshold_m_s, case.friction_corner)
    cos_g = v_rad / v_mag
    sin_g = v_circ / v_mag
    tb = math.tan(case.beta_rad) * cos_g
    cbs = 1.0 / np.sqrt(1.0 + tb * tb)
    sbs = tb * cbs
    sb, cb = math.sin(case.beta_rad), math.cos(case.beta_rad)
    press = case.k_n_m2 * x_m / (2.0 * (cb + mu * sbs))
    ei = case.ei_nm2
    r = radius_m
    x2_m = phi * (x1_m * tn - r_loc * th1 * sec2)
    normal = (2.0 * press / t_n) * r_loc * (sb - mu * cbs * (cos_g - sin_g * tn))
    if case.variant == "as_published":
        # Linearised shear (3.38) and the printed (R + 2x) factor of its derivative (3.40).
        shear = -ei / (r * r * phi * phi) * th2 + ei / (r**3 * phi) * x1_m
        d_th3 = (t_n * r**3 * phi**3) / (ei * (r + 2.0 * x_m)) * (
            th1 / phi - 1.0 + normal + ei * x2_m / (t_n * r**3 * phi * phi)
        )
    else:
        # Exact Q = dM/ds and its exact derivative: the linearised 3.38 is ~2.5 % low and
        # breaks the power balance (docs/belt-model.md, "Balances").
        shear, a_q, b_q = exact_shear(ei, th, th1, th2, x_m, x1_m, x2_m, radius_m, phi)
        # normal balance (code sign): T (th'/Phi - 1 + normal) + (dQ/dt)/Phi = 0, dQ/dt = a_q + b_q th'''
        d_th3 = -(phi * t_n * (th1 / phi - 1.0 + normal) + a_q) / b_q
    d_t = 2.0 * phi * press * r_loc * (-sb * tn + mu * cbs * (tn * cos_g + sin_g)) + (th1 - phi) * shear
    arc = phi * r_loc / c  # ds / dt
    d_m = 2.0 * mu * press * cbs * sin_g * r_loc * arc
    d_a = 0.5 * case.k_n_m2 * x_m * arc
    extras = {"sliding_speed_m_s": v_mag, "sliding_angle_rad": np.arctan2(sin_g, cos_g), "mu": mu, "pressure_n_m": press,
              "belt_speed_m_s": v_belt, "arc_m": arc}
    return d_t, d_th3, x2_m, d_m, d_a, extras


def exact_shear(ei, th, th1, th2, x_m, x1_m, x2_m, radius_m, phi):
    """Exact contact shear Q = dM/ds and its t-derivative dQ/dt = a + b * (third t-derivative of theta).

    M = EI cos(theta) (1 - th1/Phi)/(R - x) (eq 3.32 in t), ds/dt = Phi (R - x)/cos(theta);
    th1, th2, x1_m, x2_m are derivatives with respect to the normalised coordinate t.
    Returns ``(Q, a, b)``.
    """
    c, s = np.cos(th), np.sin(th)
    u = radius_m - x_m
    w = 1.0 - th1 / phi
    d = -s * th1 * w / u - c * th2 / (phi * u) + c * w * x1_m / (u * u)  # (dM/dt)/EI
    q = ei * c * d / (phi * u)
    # dd/dt without its third-derivative term (-c th3/(Phi u)), term by term of d
    a_d = (-c * th1 * th1 * w / u - s * th2 * w / u + s * th1 * th2 / (phi * u) - s * th1 * w * x1_m / (u * u)
           + s * th1 * th2 / (phi * u) - c * th2 * x1_m / (phi * u * u)
           - s * th1 * w * x1_m / (u * u) - c * th2 * x1_m / (phi * u * u) + c * w * x2_m / (u * u)
           + 2.0 * c * w * x1_m * x1_m / u**3)
    dcu = -s * th1 / u + c * x1_m / (u * u)  # d(cos(theta)/(R - x))/dt
    a = ei * (dcu * d / phi + c * a_d / (phi * u))
    b = -ei * c * c / (phi * phi * u * u)
    return q, a, b


def contact_shear(case: Case, th, th1, th2, x_m, x1_m, radius_m, phi):
    """The shear the variant's contact equations carry: exact dM/ds (corrected) or eq 3.38 (as published)."""
    if case.variant == "as_published":
        r = radius_m
        return -case.ei_nm2 / (r * r * phi * phi) * th2 + case.ei_nm2 / (r**3 * phi) * x1_m
    x2_m = phi * (x1_m * np.tan(th) - (radius_m - x_m) * th1 / np.cos(th) ** 2)
    return exact_shear(case.ei_nm2, th, th1, th2, x_m, x1_m, x2_m, radius_m, phi)[0]


def friction_shape(u, corner: float = 0.0):
    """Friction coefficient over its kinetic value vs slip speed over the threshold.

    ``corner == 0`` is the thesis's law (Fig. 3.6): linear below the threshold,
    constant above, a corner at u = 1.  ``corner > 0`` rounds the corner with a
    hyperbola of half-width ~``corner`` (C-infinity, within corner/2 of the sharp
    law and identical away from u = 1), shifted so that it is 0 at u = 0.
    """
    if corner <= 0.0:
        return np.minimum(1.0, u)
    d2 = corner * corner
    g = 0.5 * (u + 1.0 - np.sqrt((u - 1.0) ** 2 + d2))
    g0 = 0.5 * (1.0 - math.sqrt(1.0 + d2))
    return g - g0 * np.exp(-u)


def span_terms(case: Case, tau_n, v1, v2, length_m):
    """(d tau, d theta''') of one span in the normalised coordinate (physical units)."""
    ei = case.ei_nm2
    if case.variant == "as_published":
        # Appendix C rhs(21), rhs(24): L^2 and 1/L^2 swapped.
        return -length_m**2 * ei * v1 * v2, tau_n / (length_m**2 * ei) * v1
    return -(ei / length_m**2) * v1 * v2, length_m**2 * tau_n / ei * v1


def _unpack_params(case: Case, p):
    omega_s = case.omega_secondary_ref * (1.0 + CREEP_SCALE * p[K_WS])
    g = case.g_ref * (1.0 + CREEP_SCALE * p[K_G])
    return omega_s, g


def make_fun(case: Case):
    """The ``fun(t, y, p)`` of solve_bvp for ``case`` (scaled states).

    ``p`` may be the usual ``(8,)`` vector or an ``(8, m)`` array of per-column
    parameters (used by :func:`make_fun_jac` to evaluate every perturbation in
    one vectorised call).
    """

    def fun(t, y, p):
        omega_s, g = _unpack_params(case, p)
        dy = np.empty_like(y)
        for (i_t, i_th, i_th1, i_th2, i_x, i_x1), radius, phi, omega in (
            ((S_T, S_TH, S_TH1, S_TH2, S_X, S_X1), case.r_secondary_m, p[K_PHIS], omega_s),
            ((P_T, P_TH, P_TH1, P_TH2, P_X, P_X1), case.r_primary_m, p[K_PHIP], case.omega_primary_rad_s),
        ):
            t_n = y[i_t] * TENSION_REF_N
            x_m = y[i_x] * PENETRATION_REF_M
            x1_m = y[i_x1] * PENETRATION_REF_M
            d_t, d_th3, x2_m, d_m, d_a, _ = contact_terms(
                case, t_n, y[i_th], y[i_th1], y[i_th2], x_m, x1_m, radius, phi, omega, g
            )
            dy[i_t] = d_t / TENSION_REF_N
            dy[i_th] = y[i_th1]
            dy[i_th1] = y[i_th2]
            dy[i_th2] = d_th3
            dy[i_x] = y[i_x1]
            dy[i_x1] = x2_m / PENETRATION_REF_M
            if i_t == P_T:
                dy[P_M] = d_m / TORQUE_REF_NM
                dy[P_A] = d_a / AXIAL_REF_N
        for (i_tau, i_v, i_v1, i_v2, i_xp, i_yp), length in (
            ((T_TAU, T_V, T_V1, T_V2, T_XP, T_YP), p[K_LT]),
            ((L_TAU, L_V, L_V1, L_V2, L_XP, L_YP), p[K_LS]),
        ):
            d_tau, d_v3 = span_terms(case, y[i_tau] * TENSION_REF_N, y[i_v1], y[i_v2], length)
            dy[i_tau] = d_tau / TENSION_REF_N
            dy[i_v] = y[i_v1]
            dy[i_v1] = y[i_v2]
            dy[i_v2] = d_v3
            dy[i_xp] = np.cos(y[i_v])
            dy[i_yp] = np.sin(y[i_v])
        return dy

    return fun


# Column colouring of the rhs Jacobian: every region's rhs depends only on its own states
# (and a few parameters), so the j-th state of all four regions can be perturbed at once.
_BLOCKS = (
    (S_T, S_TH, S_TH1, S_TH2, S_X, S_X1),
    (P_T, P_TH, P_TH1, P_TH2, P_X, P_X1, P_M, P_A),
    (T_TAU, T_V, T_V1, T_V2, T_XP, T_YP),
    (L_TAU, L_V, L_V1, L_V2, L_XP, L_YP),
)
_BLOCK_OF_ROW = np.empty(N_STATES, dtype=int)
for _b, _rows in enumerate(_BLOCKS):
    _BLOCK_OF_ROW[list(_rows)] = _b
# Parameter groups with disjoint row supports (K_CS, K_CP do not enter the rhs).
_PARAM_GROUPS = ((K_WS, K_PHIP, K_LT, K_LS), (K_PHIS,), (K_G,))
_PARAM_ROWS = {
    K_WS: _BLOCKS[0], K_PHIS: _BLOCKS[0], K_PHIP: _BLOCKS[1], K_LT: _BLOCKS[2], K_LS: _BLOCKS[3],
    K_G: _BLOCKS[0] + _BLOCKS[1],
}
_EPS_SQRT = math.sqrt(np.finfo(float).eps)


def make_fun_jac(case: Case, fun=None):
    """``fun_jac(t, y, p)`` for solve_bvp: forward differences, coloured and vectorised.

    The same forward differences (same steps) as scipy's own estimate, but
    with the 26 state columns coloured into 8 groups (the four regions are
    uncoupled in the rhs) and the 8 parameters into 3, and all 12
    evaluations (base point included) done in one call on a 12m-column
    array: ~1/3 of the rhs work and 1/34 of its Python overhead.
    """
    fun = make_fun(case) if fun is None else fun
    n_groups = max(len(b) for b in _BLOCKS)
    n_eval = 1 + n_groups + len(_PARAM_GROUPS)

    def fun_jac(t, y, p):
        n, m = y.shape
        h_y = _EPS_SQRT * (1.0 + np.abs(y))
        h_p = _EPS_SQRT * (1.0 + np.abs(p))
        y_all = np.tile(y, (1, n_eval))
        p_all = np.repeat(p[:, None], n_eval * m, axis=1)
        for j in range(n_groups):
            cols = slice((1 + j) * m, (2 + j) * m)
            for rows in _BLOCKS:
                if j < len(rows):
                    y_all[rows[j], cols] += h_y[rows[j]]
        for g_i, group in enumerate(_PARAM_GROUPS):
            cols = slice((1 + n_groups + g_i) * m, (2 + n_groups + g_i) * m)
            for k in group:
                p_all[k, cols] += h_p[k]
        f_all = fun(np.tile(t, n_eval), y_all, p_all)
        f0 = f_all[:, :m]
        df_dy = np.zeros((n, n, m))
        for j in range(n_groups):
            diff = f_all[:, (1 + j) * m:(2 + j) * m] - f0
            for rows in _BLOCKS:
                if j < len(rows):
                    i = rows[j]
                    hi = (y[i] + h_y[i]) - y[i]
                    rr = list(rows)
                    df_dy[rr, i, :] = diff[rr] / hi
        df_dp = np.zeros((n, N_PARAMS, m))
        for g_i, group in enumerate(_PARAM_GROUPS):
            diff = f_all[:, (1 + n_groups + g_i) * m:(2 + n_groups + g_i) * m] - f0
            for k in group:
                hk = (p[k] + h_p[k]) - p[k]
                rr = list(_PARAM_ROWS[k])
                df_dp[rr, k, :] = diff[rr] / hk
        return df_dy, df_dp

    return fun_jac


def make_bc(case: Case):
    """The ``bc(ya, yb, p)`` of solve_bvp for ``case`` (34 residuals, O(1) scaled)."""
    from dyno.model import balance  # imports this module: bound at call time

    r_s, r_p, lc = case.r_secondary_m, case.r_primary_m, case.centre_distance_m
    published = case.variant == "as_published"

    def bc(ya, yb, p):
        phi_s, phi_p, c_s, c_p, l_t, l_s = p[K_PHIS], p[K_PHIP], p[K_CS], p[K_CP], p[K_LT], p[K_LS]
        xs0, xs1 = ya[S_X] * PENETRATION_REF_M, yb[S_X] * PENETRATION_REF_M
        xp0, xp1 = ya[P_X] * PENETRATION_REF_M, yb[P_X] * PENETRATION_REF_M
        # Entry/exit directions w.r.t. +x (5.21-5.24; 5.23 with -theta_S1).
        e_st = math.pi / 2 - c_s - yb[S_TH]
        e_ss = 3 * math.pi / 2 - c_s - phi_s - ya[S_TH]
        e_pt = c_p - math.pi / 2 - ya[P_TH]
        e_ps = c_p + phi_p - 3 * math.pi / 2 - yb[P_TH]
        # Contact end points (5.17-5.20 with the code's labels).
        pts = {
            "st": (lc - r_s * math.cos(c_s), r_s * math.sin(c_s)),
            "ss": (lc - r_s * math.cos(c_s + phi_s), r_s * math.sin(c_s + phi_s)),
            "pt": (r_p * math.cos(c_p), r_p * math.sin(c_p)),
            "ps": (r_p * math.cos(c_p + phi_p), r_p * math.sin(c_p + phi_p)),
        }

        def curvature(th, th1, x_m, radius, phi):
            return math.cos(th) / (radius - x_m) * (1.0 - th1 / phi)

        def shear(th2, x1_scaled, radius, phi, th=0.0, th1=0.0, x_scaled=0.0):
            x1 = x1_scaled * PENETRATION_REF_M
            if published:
                return -th2 + x1 / radius
            # exact dM/ds = 0, times Phi (R - x)/(EI cos(theta)): -th2 + Phi x1/R when linearised
            w = 1.0 - th1 / phi
            return -math.tan(th) * th1 * w * phi - th2 + phi * w * x1 / (radius - x_scaled * PENETRATION_REF_M)

        torque_points = 0.0
        if not published:
            # The interface point loads act on the pulley too: the imposed torque is the total.
            torque_points = balance.point_load_torque_nm(balance.interface_loads_at_ends(case, ya, yb, p), "primary")
        if case.bc == "slack_tension":
            level = yb[P_T] - case.slack_tension_n / TENSION_REF_N
        else:
            level = yb[P_A] - case.axial_force_n / AXIAL_REF_N
        res = [
            ya[S_X],
            yb[S_X],
            (ya[S_X1] * PENETRATION_REF_M + phi_s * (r_s - xs0) * math.tan(ya[S_TH])) / PENETRATION_REF_M,
            yb[P_M] + (case.torque_nm - torque_points) / TORQUE_REF_NM,
            level,
            ya[P_X],
            yb[P_X],
            ya[P_M],
            (ya[P_X1] * PENETRATION_REF_M + phi_p * (r_p - xp0) * math.tan(ya[P_TH])) / PENETRATION_REF_M,
            ya[P_A],
            # tension continuity (5.47-5.50)
            ya[S_T] - yb[L_TAU],
            yb[S_T] - ya[T_TAU],
            ya[P_T] - yb[T_TAU],
            yb[P_T] - ya[L_TAU],
            # direction continuity (5.35-5.38)
            e_ss - yb[L_V],
            e_st + math.pi - ya[T_V],
            e_pt + math.pi - yb[T_V],
            e_ps - ya[L_V],
            # curvature continuity (5.39-5.42), made dimensionless with the radius
            r_s * (curvature(ya[S_TH], ya[S_TH1], xs0, r_s, phi_s) - yb[L_V1] / l_s),
            r_s * (curvature(yb[S_TH], yb[S_TH1], xs1, r_s, phi_s) - ya[T_V1] / l_t),
            r_p * (curvature(ya[P_TH], ya[P_TH1], xp0, r_p, phi_p) - yb[T_V1] / l_t),
            r_p * (curvature(yb[P_TH], yb[P_TH1], xp1, r_p, phi_p) - ya[L_V1] / l_s),
            # zero shear (5.43-5.46); as published, bc(26) reads the entry x'.
            shear(ya[S_TH2], ya[S_X1], r_s, phi_s, ya[S_TH], ya[S_TH1], ya[S_X]),
            shear(yb[S_TH2], yb[S_X1], r_s, phi_s, yb[S_TH], yb[S_TH1], yb[S_X]),
            shear(ya[P_TH2], ya[P_X1], r_p, phi_p, ya[P_TH], ya[P_TH1], ya[P_X]),
            shear(yb[P_TH2], ya[P_X1] if published else yb[P_X1], r_p, phi_p, yb[P_TH], yb[P_TH1], yb[P_X]),
            # position continuity (5.27-5.34), in mm
            (pts["st"][0] - ya[T_XP] * l_t) / POSITION_BC_REF_M,
            (pts["st"][1] - ya[T_YP] * l_t) / POSITION_BC_REF_M,
            (pts["ss"][0] - yb[L_XP] * l_s) / POSITION_BC_REF_M,
            (pts["ss"][1] - yb[L_YP] * l_s) / POSITION_BC_REF_M,
            (pts["pt"][0] - yb[T_XP] * l_t) / POSITION_BC_REF_M,
            (pts["pt"][1] - yb[T_YP] * l_t) / POSITION_BC_REF_M,
            (pts["ps"][0] - ya[L_XP] * l_s) / POSITION_BC_REF_M,
            (pts["ps"][1] - ya[L_YP] * l_s) / POSITION_BC_REF_M,
        ]
        return np.array(res)

    return bc


# ---- initial guess --------------------------------------------------------------------------


def _smoothstep(t):
    return t * t * (3.0 - 2.0 * t)


def _span_bending_length_m(case: Case, tension_n: float) -> float:
    ei_eff = case.ei_nm2
    if case.variant == "as_published":
        ei_eff = case.ei_nm2 * 0.2**4  # swapped L^2 terms: EI L^4 with L ~ the span length
    return math.sqrt(ei_eff / max(tension_n, 1.0))


def initial_guess(case: Case, n_nodes: int = 301):
    """Geometric initial guess ``(t, y, p)``; needs no starting solution."""
    from dyno.model.closed_form import closed_form_point  # noqa: F401  (tension level estimate below)

    r_p, r_s, lc = case.r_primary_m, case.r_secondary_m, case.centre_distance_m
    dt_n = case.torque_nm / r_p
    if case.bc == "slack_tension":
        t_slack = case.slack_tension_n
    else:
        # Frictional-wedge estimate of the driver thrust (closed form, eq 17 with rho = 0).
        wedge = 2.0 * math.tan(case.beta_rad + math.atan(case.mu))
        t_tight = case.axial_force_n * wedge / math.pi
        t_slack = max(t_tight - dt_n, 0.2 * dt_n)
    t_tight = t_slack + dt_n
    theta_t = geometry.tangent_angle_rad(r_p, r_s, lc)
    d_pt = _span_bending_length_m(case, t_tight) / r_p
    d_ps = _span_bending_length_m(case, t_slack) / r_p
    d_st = _span_bending_length_m(case, t_tight) / r_s
    d_ss = _span_bending_length_m(case, t_slack) / r_s
    c_p = math.pi / 2 + theta_t + d_pt
    phi_p = math.pi - 2 * theta_t - d_pt - d_ps
    c_s = math.pi / 2 - theta_t + d_st
    phi_s = math.pi + 2 * theta_t - d_ss - d_st
    if phi_p < 0.3 or phi_s < 0.3:
        phi_p, phi_s = max(phi_p, 0.3), max(phi_s, 0.3)

    t = np.linspace(0.0, 1.0, n_nodes)
    y = np.zeros((N_STATES, n_nodes))
    delta = 0.04
    ramp = (1.0 - np.exp(-t / delta)) * (1.0 - np.exp(-(1.0 - t) / delta))
    ramp /= ramp.max()
    tanb = math.tan(case.beta_rad)
    for (i_t, i_th, i_th1, i_th2, i_x, i_x1), radius, phi, t_in, t_out in (
        ((S_T, S_TH, S_TH1, S_TH2, S_X, S_X1), r_s, phi_s, t_slack, t_tight),
        ((P_T, P_TH, P_TH1, P_TH2, P_X, P_X1), r_p, phi_p, t_tight, t_slack),
    ):
        tension = t_in + (t_out - t_in) * _smoothstep(t)
        x_m = tension / (radius * case.k_n_m2 * tanb) * ramp
        x1_m = np.gradient(x_m, t)
        th = -np.arctan(x1_m / phi / (radius - x_m))
        th1 = np.gradient(th, t)
        th2 = np.gradient(th1, t)
        y[i_t] = tension / TENSION_REF_N
        y[i_th], y[i_th1], y[i_th2] = th, th1, th2
        y[i_x], y[i_x1] = x_m / PENETRATION_REF_M, x1_m / PENETRATION_REF_M
        if i_t == P_T:
            y[P_M] = -(t_tight - tension) * r_p / TORQUE_REF_NM
            arc = phi * (radius - x_m) / np.cos(th)
            integrand = 0.5 * case.k_n_m2 * x_m * arc
            y[P_A] = np.concatenate([[0.0], np.cumsum(0.5 * (integrand[1:] + integrand[:-1]) * np.diff(t))]) / AXIAL_REF_N

    def chord(a, b):
        dx, dy_ = b[0] - a[0], b[1] - a[1]
        return math.hypot(dx, dy_), math.atan2(dy_, dx)

    st = (lc - r_s * math.cos(c_s), r_s * math.sin(c_s))
    ss = (lc - r_s * math.cos(c_s + phi_s), r_s * math.sin(c_s + phi_s))
    pt = (r_p * math.cos(c_p), r_p * math.sin(c_p))
    ps = (r_p * math.cos(c_p + phi_p), r_p * math.sin(c_p + phi_p))
    l_t, ang_t = chord(st, pt)
    l_s, ang_s = chord(ps, ss)
    ang_t = ang_t % (2 * math.pi)  # ~ pi, matching the E_St + pi convention
    ang_s = (ang_s + math.pi) % (2 * math.pi) - math.pi  # ~ 0
    for (i_tau, i_v, i_v1, i_v2, i_xp, i_yp), start, end, length, ang, tension in (
        ((T_TAU, T_V, T_V1, T_V2, T_XP, T_YP), st, pt, l_t, ang_t, t_tight),
        ((L_TAU, L_V, L_V1, L_V2, L_XP, L_YP), ps, ss, l_s, ang_s, t_slack),
    ):
        y[i_tau] = tension / TENSION_REF_N
        y[i_v] = ang
        y[i_xp] = (start[0] + (end[0] - start[0]) * t) / length
        y[i_yp] = (start[1] + (end[1] - start[1]) * t) / length
    p = np.zeros(N_PARAMS)
    p[K_PHIS], p[K_PHIP], p[K_CS], p[K_CP], p[K_LT], p[K_LS] = phi_s, phi_p, c_s, c_p, l_t, l_s
    # Creep guesses: belt leaves the driver at the slack strain (Reynolds).
    ea = case.ea_n
    v0 = case.omega_primary_rad_s * r_p
    fc = case.mass_kg_m * v0 * v0
    eps_t, eps_s = (t_tight + fc) / ea, (t_slack + fc) / ea
    p[K_G] = (1.0 / (1.0 + eps_t) - 1.0) / CREEP_SCALE
    p[K_WS] = ((1.0 + eps_s) / (1.0 + eps_t) - 1.0) / CREEP_SCALE - 5.0  # driven pulley slips a little more
    return t, y, p


def _contact_points(case: Case, p):
    r_s, r_p, lc = case.r_secondary_m, case.r_primary_m, case.centre_distance_m
    c_s, phi_s, c_p, phi_p = p[K_CS], p[K_PHIS], p[K_CP], p[K_PHIP]
    return {
        "st": complex(lc - r_s * math.cos(c_s), r_s * math.sin(c_s)),
        "ss": complex(lc - r_s * math.cos(c_s + phi_s), r_s * math.sin(c_s + phi_s)),
        "pt": complex(r_p * math.cos(c_p), r_p * math.sin(c_p)),
        "ps": complex(r_p * math.cos(c_p + phi_p), r_p * math.sin(c_p + phi_p)),
    }


def _belt_speed(case: Case, g, t_n):
    return g * (t_n + case.ea_n) / (case.ea_n * case.mass_kg_m - g * g)


def _mass_flow_for_speed(case: Case, v, t_n):
    """Inverse of :func:`_belt_speed` in G (the root of V G^2 + (T + EA) G - V EA m = 0)."""
    b = t_n + case.ea_n
    return (-b + math.sqrt(b * b + 4.0 * v * v * case.ea_n * case.mass_kg_m)) / (2.0 * v)


def _transfer_speeds(old: Case, new: Case, y: np.ndarray, p: np.ndarray) -> None:
    """Keep the sliding-velocity field when the radii, speed or belt constants change (in place).

    The friction law turns over within v_th (1e-4 m/s) of zero slip, i.e.
    within 1e-5 of the belt speed: left alone, the mass-flow and secondary
    creeps of the old solution give sliding speeds tens of v_th off after a
    1 % change of radius (the x*omega and centrifugal terms do not scale with
    R).  So the mass flow is set to keep V - (R - x) omega at the primary's
    point of least slip, and the secondary speed to keep it at the
    secondary's.
    """
    omega_s_old, g_old = _unpack_params(old, p)
    # primary: the point of least slip (the adhesion zone, if any)
    t_p = y[P_T] * TENSION_REF_N
    x_p = y[P_X] * PENETRATION_REF_M
    v_old = _belt_speed(old, g_old, t_p)
    slip = np.abs(v_old * np.cos(y[P_TH]) - (old.r_primary_m - x_p) * old.omega_primary_rad_s)
    j = int(np.argmin(slip))
    surf_shift = (new.r_primary_m - x_p[j]) * new.omega_primary_rad_s - (old.r_primary_m - x_p[j]) * old.omega_primary_rad_s
    v_new = v_old[j] + surf_shift / math.cos(y[P_TH, j])
    if not (math.isfinite(v_new) and v_new > 0):
        return
    g_new = _mass_flow_for_speed(new, v_new, t_p[j])
    p[K_G] = (g_new / new.g_ref - 1.0) / CREEP_SCALE
    # secondary: keep the sliding speed at its point of least slip
    t_s = y[S_T] * TENSION_REF_N
    x_s = y[S_X] * PENETRATION_REF_M
    vs_old = _belt_speed(old, g_old, t_s)
    slip_s = vs_old * np.cos(y[S_TH]) - (old.r_secondary_m - x_s) * omega_s_old
    k = int(np.argmin(np.abs(slip_s)))
    vs_new = _belt_speed(new, g_new, t_s[k])
    omega_s_new = (vs_new * math.cos(y[S_TH, k]) - slip_s[k]) / (new.r_secondary_m - x_s[k])
    p[K_WS] = (omega_s_new / new.omega_secondary_ref - 1.0) / CREEP_SCALE


def transfer_guess(old: Case, new: Case, y: np.ndarray, p: np.ndarray):
    """Adapt a converged solution of ``old`` into a guess for ``new``.

    Wrap and orientation angles move with the geometric tangent angle, the
    spans are carried by the similarity transform that maps their old end
    points onto the new ones (so their shape, normalised curvature and
    direction changes are kept).  Tensions are left alone: rescaling them to
    the new level measured slower (the adhesion zone's position matters more).
    """
    y, p = y.copy(), p.copy()
    _transfer_speeds(old, new, y, p)
    d_t = geometry.tangent_angle_rad(new.r_primary_m, new.r_secondary_m, new.centre_distance_m) - geometry.tangent_angle_rad(
        old.r_primary_m, old.r_secondary_m, old.centre_distance_m
    )
    p[K_PHIP] -= 2 * d_t
    p[K_PHIS] += 2 * d_t
    p[K_CP] += d_t
    p[K_CS] -= d_t
    if new.ei_nm2 != old.ei_nm2 or new.variant != old.variant:
        # The wrap lost to arching at each contact end goes like sqrt(EI/T)/R (as in initial_guess).
        t_tight, t_slack = y[P_T, 0] * TENSION_REF_N, y[P_T, -1] * TENSION_REF_N

        def lost(case, tension, radius):
            return _span_bending_length_m(case, tension) / radius

        d_pt = lost(new, t_tight, new.r_primary_m) - lost(old, t_tight, old.r_primary_m)
        d_ps = lost(new, t_slack, new.r_primary_m) - lost(old, t_slack, old.r_primary_m)
        d_st = lost(new, t_tight, new.r_secondary_m) - lost(old, t_tight, old.r_secondary_m)
        d_ss = lost(new, t_slack, new.r_secondary_m) - lost(old, t_slack, old.r_secondary_m)
        if p[K_PHIP] - d_pt - d_ps > 0.3 and p[K_PHIS] - d_st - d_ss > 0.3:
            p[K_CP] += d_pt
            p[K_PHIP] -= d_pt + d_ps
            p[K_CS] += d_st
            p[K_PHIS] -= d_ss + d_st
    # Spans: similarity transform of the old curves onto the new end points.
    old_pts, new_pts = _contact_points(old, p), _contact_points(new, p)
    for rows, k_len, a, b in (
        ((T_XP, T_YP, T_V), K_LT, "st", "pt"),
        ((L_XP, L_YP, L_V), K_LS, "ps", "ss"),
    ):
        length = p[k_len]
        z = (y[rows[0]] + 1j * y[rows[1]]) * length
        za, zb = z[0], z[-1]
        scale = (new_pts[b] - new_pts[a]) / (zb - za)
        z_new = new_pts[a] + scale * (z - za)
        new_len = length * abs(scale)
        y[rows[0]], y[rows[1]] = z_new.real / new_len, z_new.imag / new_len
        y[rows[2]] += math.atan2(scale.imag, scale.real)
        p[k_len] = new_len
    return y, p


# ---- solver driver --------------------------------------------------------------------------


def remesh(t_old: np.ndarray, n_nodes: int) -> np.ndarray:
    """A mesh of ``n_nodes`` that keeps the old mesh's density (3/4) blended with uniform (1/4).

    solve_bvp refines by inserting nodes and never removes any; re-meshing
    between continuation steps keeps the node count, and SuperLU's memory,
    bounded while keeping nodes where the boundary layers are.
    """
    u = np.linspace(0.0, len(t_old) - 1.0, n_nodes)
    dens = np.interp(u, np.arange(len(t_old)), t_old)
    mesh = 0.75 * dens + 0.25 * np.linspace(0.0, 1.0, n_nodes)
    mesh[0], mesh[-1] = 0.0, 1.0
    return mesh


def equidistributed_mesh(t_old: np.ndarray, rms_residuals: np.ndarray, tol: float, n_min: int = 120,
                         n_max: int = 4000, target_fraction: float = 0.25, order: int = 3,
                         uniform_share: float = 0.1) -> np.ndarray:
    """A mesh that equidistributes the collocation residual of a converged solution.

    On interval i of width h_i the RMS residual behaves like r_i ~ K_i h_i^order
    (cubic collocation: the residual of y' is third order), so the
    width giving ``target_fraction * tol`` there is h_i (target/r_i)^(1/order),
    i.e. a node density rho_i = (r_i/target)^(1/order)/h_i.  The density is
    smoothed over neighbouring intervals (a kink does not follow the power
    law), blended with a uniform floor (``uniform_share`` of the nodes), and
    the node count is what it integrates to, clipped to [n_min, n_max].
    Unlike :func:`remesh` this removes nodes where the old mesh was
    needlessly dense (solve_bvp only ever adds), e.g. where an adhesion zone
    was before a parameter change.
    """
    h = np.diff(t_old)
    r = np.maximum(np.asarray(rms_residuals, dtype=float), 1e-6 * tol)
    dens = (r / (target_fraction * tol)) ** (1.0 / order) / h
    # smooth: each interval takes the max of itself and its neighbours
    dens = np.maximum(dens, np.maximum(np.r_[dens[1:], dens[-1]], np.r_[dens[0], dens[:-1]]))
    n_eq = float(np.sum(dens * h))
    n = int(np.clip(n_eq / (1.0 - uniform_share), n_min, n_max))
    dens = dens + uniform_share * n_eq / (1.0 - uniform_share)
    cum = np.concatenate([[0.0], np.cumsum(dens * h)])
    mesh = np.interp(np.linspace(0.0, cum[-1], n), cum, t_old)
    mesh[0], mesh[-1] = 0.0, 1.0
    return np.unique(mesh)


@dataclass
class StepRecord:
    step: int
    slip_threshold_m_s: float
    status: int
    residual_max: float
    nodes: int
    seconds: float
    what: str = ""


@dataclass
class RawSolution:
    """What solve_bvp returned for one case, plus the continuation history."""

    case: Case
    t: np.ndarray
    y: np.ndarray
    p: np.ndarray
    sol: object  # scipy PPoly-like callable from solve_bvp
    residual_max: float
    bc_residual_max: float
    tol: float
    history: list = field(default_factory=list)
    solve_s: float = 0.0
    rms_residuals: np.ndarray | None = None  # per mesh interval, from solve_bvp (drives re-meshing)


def _sanity_problem(case: Case, y: np.ndarray, p: np.ndarray) -> str | None:
    """Physical sanity of a converged solution; a message if it is nonsense."""
    if not (0.05 < p[K_PHIP] < 2 * math.pi and 0.05 < p[K_PHIS] < 2 * math.pi):
        return f"wrap angles out of range (Phi_P={p[K_PHIP]:.3g}, Phi_S={p[K_PHIS]:.3g} rad)"
    if p[K_LT] <= 0 or p[K_LS] <= 0:
        return "negative span length"
    tensions = np.concatenate([y[S_T], y[P_T], y[T_TAU], y[L_TAU]]) * TENSION_REF_N
    if not np.all(np.isfinite(tensions)) or tensions.min() <= 0:
        return f"non-positive tractive tension (min {np.nanmin(tensions):.3g} N)"
    if np.abs(y[[S_TH, P_TH]]).max() > 1.2:
        return "inclination angle beyond 70 degrees"
    from dyno.model.capstan import max_tension_ratio

    for name, i_t, k_phi in (("primary", P_T, K_PHIP), ("secondary", S_T, K_PHIS)):
        t_n = y[i_t]
        if t_n.max() / t_n.min() > max_tension_ratio(p[k_phi], case.mu, case.beta_rad):
            return f"{name} tension ratio beyond the capstan bound (gross slip)"
    if abs(p[K_WS]) * CREEP_SCALE > 0.5:
        return f"secondary speed {1 + p[K_WS] * CREEP_SCALE:.3g} x its no-slip value (gross slip)"
    return None


_SPLU_LOCK = threading.Lock()


def _block_global_jac(n, m, k, i_jac, j_jac, h, df_dy, df_dy_middle, df_dp, df_dp_middle, dbc_dya, dbc_dyb, dbc_dp):
    """scipy's ``construct_global_jac`` for this model, exploiting the block-diagonal rhs Jacobian.

    Same formulas (Kierzenka & Shampine's Lobatto IIIA collocation blocks)
    as ``scipy.integrate._bvp.construct_global_jac``, but the n x n products
    are formed region by region (6, 8, 6, 6 states: 1/15 of the flops) and
    only structurally non-zero entries enter the sparse matrix (~1/3).
    """
    from scipy.sparse import coo_matrix

    h3 = h[:, None, None]
    rows, cols, vals = [], [], []
    base = (np.arange(m - 1) * n)[:, None, None]
    for blk in _BLOCKS:
        idx = np.asarray(blk)
        b = idx.size
        a = np.transpose(df_dy[idx[:, None], idx[None, :], :], (2, 0, 1))
        a_mid = np.transpose(df_dy_middle[idx[:, None], idx[None, :], :], (2, 0, 1))
        eye = np.identity(b)
        d0 = -eye - h3 / 6 * (a[:-1] + 2 * a_mid) - h3**2 / 12 * np.einsum("...ij,...jk->...ik", a_mid, a[:-1])
        d1 = eye - h3 / 6 * (a[1:] + 2 * a_mid) + h3**2 / 12 * np.einsum("...ij,...jk->...ik", a_mid, a[1:])
        r = np.broadcast_to(base + idx[None, :, None], (m - 1, b, b))
        c = np.broadcast_to(base + idx[None, None, :], (m - 1, b, b))
        rows += [r.ravel(), r.ravel()]
        cols += [c.ravel(), (c + n).ravel()]
        vals += [d0.ravel(), d1.ravel()]
    # boundary conditions on ya, yb
    bc_r = (m - 1) * n + np.arange(n + k)[:, None]
    rows += [np.broadcast_to(bc_r, (n + k, n)).ravel()] * 2
    cols += [np.broadcast_to(np.arange(n)[None, :], (n + k, n)).ravel(),
             np.broadcast_to((m - 1) * n + np.arange(n)[None, :], (n + k, n)).ravel()]
    vals += [dbc_dya.ravel(), dbc_dyb.ravel()]
    if k > 0:
        fp = np.transpose(df_dp, (2, 0, 1))
        fp_mid = np.transpose(df_dp_middle, (2, 0, 1)).copy()
        a_mid_full = np.transpose(df_dy_middle, (2, 0, 1))
        diff = fp[:-1] - fp[1:]
        for blk in _BLOCKS:
            idx = np.asarray(blk)
            fp_mid[:, idx, :] += 0.125 * h3 * np.einsum("...ij,...jk->...ik", a_mid_full[:, idx[:, None], idx[None, :]],
                                                       diff[:, idx, :])
        d_p = -h3 / 6 * (fp[:-1] + fp[1:] + 4 * fp_mid)
        rows += [np.broadcast_to((base[:, :, 0] + np.arange(n)[None, :])[:, :, None], (m - 1, n, k)).ravel(),
                 np.broadcast_to(bc_r, (n + k, k)).ravel()]
        cols += [np.broadcast_to(n * m + np.arange(k)[None, None, :], (m - 1, n, k)).ravel(),
                 np.broadcast_to(n * m + np.arange(k)[None, :], (n + k, k)).ravel()]
        vals += [d_p.ravel(), dbc_dp.ravel()]
    size = n * m + k
    jac = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size))
    return jac.tocsc()


@contextlib.contextmanager
def _fast_collocation_linear_algebra():
    """Speed up solve_bvp's linear algebra for this model (same Newton iterates up to rounding).

    * ``construct_global_jac`` -> :func:`_block_global_jac` (the rhs
      Jacobian is block-diagonal by region);
    * ``splu``: the collocation Jacobian is block-bidiagonal (plus the
      boundary rows and the parameter columns) with diagonal blocks near -I:
      in its natural order with threshold pivoting (0.1) it fills in less
      than after COLAMD, and dropping explicit zeros first makes the
      factorisation 3-5x faster (measured at 1550 nodes: 0.07-0.08 s vs
      0.2-0.4 s).

    scipy's ``solve_bvp`` has no options for either, so the two module-level
    names in ``scipy.integrate._bvp`` are swapped for the duration of the
    call (under a lock; restored after).  If the private names ever
    disappear, scipy's defaults are used.
    """
    import scipy.integrate._bvp as _bvp_mod

    original_splu = getattr(_bvp_mod, "splu", None)
    original_jac = getattr(_bvp_mod, "construct_global_jac", None)
    if original_splu is None or original_jac is None:
        yield
        return

    def splu_natural(a, *args, **kwargs):
        a.eliminate_zeros()
        kwargs.setdefault("permc_spec", "NATURAL")
        kwargs.setdefault("diag_pivot_thresh", 0.1)
        return original_splu(a, *args, **kwargs)

    def global_jac(n, *args):
        if n != N_STATES:
            return original_jac(n, *args)
        return _block_global_jac(n, *args)

    with _SPLU_LOCK:
        _bvp_mod.splu, _bvp_mod.construct_global_jac = splu_natural, global_jac
        try:
            yield
        finally:
            _bvp_mod.splu, _bvp_mod.construct_global_jac = original_splu, original_jac


def _slip_diagnosis(case: Case, y: np.ndarray, p: np.ndarray) -> str:
    """How close the last converged solution of a stalled continuation was to gross slip.

    A pulley whose belt slides everywhere by much more than v_th is near its
    torque capacity: past it there is no steady solution (the capstan/Gerbert
    bound on the tension ratio with the arched, shrinking wrap), so a stall
    there is the physics, not the solver.
    """
    from dyno.model.capstan import max_tension_ratio

    try:
        omega_s, g = _unpack_params(case, p)
        parts = []
        for name, i_t, i_th, i_x, k_phi, radius, omega in (
            ("primary", P_T, P_TH, P_X, K_PHIP, case.r_primary_m, case.omega_primary_rad_s),
            ("secondary", S_T, S_TH, S_X, K_PHIS, case.r_secondary_m, omega_s),
        ):
            t_n = y[i_t] * TENSION_REF_N
            v = _belt_speed(case, g, t_n)
            x_m = y[i_x] * PENETRATION_REF_M
            slip = np.hypot(v * np.sin(y[i_th]), v * np.cos(y[i_th]) - (radius - x_m) * omega)
            use = t_n.max() / t_n.min() / max_tension_ratio(p[k_phi], case.mu, case.beta_rad)
            gross = slip.min() > 100 * case.slip_threshold_m_s and use > 0.5
            parts.append(f"{name}: min sliding {slip.min():.3g} m/s, tension ratio at {100 * use:.0f} % of its "
                         f"capstan bound{' - approaching gross slip, no steady solution beyond' if gross else ''}")
        return f" [last converged point ({case.name()}): " + "; ".join(parts) + "]"
    except Exception:  # the diagnosis must never hide the failure itself
        return ""


def _solve_once(case: Case, t, y, p, tol: float, max_nodes: int):
    from scipy.integrate import solve_bvp

    fun, bc = make_fun(case), make_bc(case)
    fun_jac = make_fun_jac(case, fun)
    with np.errstate(all="ignore"), _fast_collocation_linear_algebra():
        res = solve_bvp(fun, bc, t, y, p, tol=tol, max_nodes=max_nodes, bc_tol=tol, fun_jac=fun_jac)
    rms = float(np.max(res.rms_residuals)) if res.rms_residuals is not None and len(res.rms_residuals) else float("inf")
    bc_res = float(np.max(np.abs(bc(res.y[:, 0], res.y[:, -1], res.p))))
    ok = res.status == 0 and np.isfinite(rms) and bc_res <= 10 * tol
    problem = _sanity_problem(case, res.y, res.p) if ok else None
    return res, rms, bc_res, ok and problem is None, problem


def _interp_case(a: Case, b: Case, s: float) -> Case:
    """Homotopy between two cases: geometric in EI and the slip threshold, linear otherwise."""
    changes = {}
    for f_ in fields(Case):
        va, vb = getattr(a, f_.name), getattr(b, f_.name)
        if isinstance(va, str):
            changes[f_.name] = vb
        elif f_.name in ("ei_nm2", "slip_threshold_m_s", "k_n_m2"):
            changes[f_.name] = va * (vb / va) ** s
        elif isinstance(va, float) and math.isnan(va):
            changes[f_.name] = vb
        else:
            changes[f_.name] = va + (vb - va) * s
    return replace(a, **changes)


def solve_case(
    case: Case,
    *,
    guess: RawSolution | None = None,
    tol: float = 1e-3,
    nodes: int = 300,
    max_nodes: int = 8000,
    start_slip_m_s: float = 1.0,
    slip_factor: float = 0.4,
    max_halvings: int = 6,
    time_limit_s: float = 120.0,
    keep_mesh_below: int = 0,
    mesh_mode: str = "equidistribute",
    step_node_factor: float = 4.0,
    min_fraction: float = 2e-3,
    log=None,
) -> RawSolution:
    """Solve one case, by slip-threshold continuation from the geometric guess or by homotopy from ``guess``.

    Raises :class:`~dyno.errors.DidNotConverge` naming the case, the
    continuation step and the last residual.
    """
    t0 = time.perf_counter()
    history: list[StepRecord] = []
    last = {"rms": float("nan"), "step": 0, "msg": ""}

    def attempt(c: Case, t, y, p, what: str):
        ts = time.perf_counter()
        # A step that needs many times its starting mesh is usually a step too far (Newton
        # wandering): cap it so it fails fast and the step is halved.
        step_nodes = min(max_nodes, max(int(step_node_factor * t.size), 1500))
        res, rms, bc_res, ok, problem = _solve_once(c, t, y, p, tol, step_nodes)
        history.append(StepRecord(len(history) + 1, c.slip_threshold_m_s, res.status, rms, res.x.size,
                                  time.perf_counter() - ts, what))
        last.update(rms=rms, step=len(history), msg=problem or res.message)
        if log is not None:
            log(history[-1])
        return res, rms, bc_res, ok

    def fail(reason: str):
        if "gross slip" in reason or "gross slip" in last["msg"]:
            raise GrossSlip(
                f"gross slip: the belt cannot transmit {case.torque_nm:g} N*m at this tension level for {case.name()} "
                f"(no steady solution: {reason}; last step: {last['msg']})"
            )
        raise DidNotConverge(
            f"belt model did not converge for {case.name()}: {reason} at continuation step {last['step']} "
            f"(last residual {last['rms']:.3g}, tol {tol:g}; {last['msg']})"
        )

    def new_mesh(t, rms):
        if rms is not None and len(rms) == t.size - 1 and mesh_mode == "equidistribute":
            return equidistributed_mesh(t, rms, tol, n_min=min(nodes, 120), n_max=max_nodes // 2)
        return remesh(t, nodes)

    def march(start: Case, target: Case, t, y, p, first_fraction: float, what: str, max_fraction: float = 1.0,
              rms=None):
        """Homotopy from ``start`` (solved: t, y, p) to ``target``; adaptive step."""
        s, ds = 0.0, first_fraction
        halvings = 0
        best = None
        c_prev = start
        while s < 1.0:
            if time.perf_counter() - t0 > time_limit_s:
                fail(f"time limit {time_limit_s:g} s during {what} at fraction {s:.3g}" + _slip_diagnosis(c_prev, y, p))
            s_new = min(1.0, s + ds)
            c = _interp_case(start, target, s_new)
            if t.size > keep_mesh_below:
                mesh = new_mesh(t, rms)
                from scipy.interpolate import PchipInterpolator

                y_guess = PchipInterpolator(t, y, axis=1)(mesh)
            else:
                mesh, y_guess = t, y
            y_guess, p_guess = transfer_guess(c_prev, c, y_guess, p)
            res, rms_max, bc_res, ok = attempt(c, mesh, y_guess, p_guess, f"{what} s={s_new:.3g}")
            if ok:
                s = s_new
                c_prev = c
                t, y, p, rms = res.x, res.y, res.p, res.rms_residuals
                best = (c, res, rms_max, bc_res)
                halvings = 0
                ds = min(ds * 1.5, max_fraction)
            else:
                halvings += 1
                ds = 0.5 * min(ds, 1.0 - s)  # a grown ds may have been clipped at 1: halve the step tried
                if halvings > max_halvings or ds < min_fraction:
                    fail(f"{what} stalled at fraction {s:.3g}" + _slip_diagnosis(c_prev, y, p))
        return best

    if guess is not None:
        start = replace(guess.case)
        target = case
        if start.bc != target.bc:
            # Switch the tension-level BC at the guess's own operating point first.
            level = replace(start, bc=target.bc)
            if target.bc == "primary_axial_force":
                level = replace(level, axial_force_n=float(guess.y[P_A, -1] * AXIAL_REF_N))
            else:
                level = replace(level, slack_tension_n=float(guess.y[P_T, -1] * TENSION_REF_N))
            start = level
        best = march(start, target, guess.t, guess.y, guess.p, 1.0, "warm-start homotopy", rms=guess.rms_residuals)
    else:
        t, y, p = initial_guess(case, nodes)
        # From the guess, solve with a heavily smoothed friction law first.
        v_start = max(start_slip_m_s, case.slip_threshold_m_s)
        c0 = replace(case, slip_threshold_m_s=v_start)
        res, rms, bc_res, ok = attempt(c0, t, y, p, "geometric guess")
        if ok:
            best = (c0, res, rms, bc_res)
        else:
            # Unequal radii: the straight-span guess is far off (the arching differs a lot between a
            # small and a large pulley).  Solve at equal radii (same belt length) with the smooth
            # friction law, then continue in the radii to the target.
            lc = case.centre_distance_m
            r_eq = geometry.equal_radius_m(geometry.belt_length_m(case.r_primary_m, case.r_secondary_m, lc), lc)
            # The geometric guess is fragile in the torque too (it may fail at one torque and work at
            # twice or half of it): try a few anchor torques; the march below moves torque and radii.
            for torque_nm in (case.torque_nm, 1.8 * case.torque_nm, 0.5 * case.torque_nm):
                anchor = replace(c0, r_primary_m=r_eq, r_secondary_m=r_eq, torque_nm=torque_nm)
                t, y, p = initial_guess(anchor, nodes)
                res, rms, bc_res, ok = attempt(anchor, t, y, p, f"geometric guess at equal radii, {torque_nm:g} N*m")
                if ok:
                    break
            else:
                fail("first solve from the geometric initial guess failed (also at equal radii, torque x1, x1.8, x0.5)")
            best = march(anchor, c0, res.x, res.y, res.p, 0.25, "ratio continuation", rms=res.rms_residuals)
            res = best[1]
        if v_start > case.slip_threshold_m_s:
            n_steps = math.log(v_start / case.slip_threshold_m_s) / -math.log(slip_factor)
            frac = 1.0 / max(n_steps, 1.0)
            best = march(c0, case, res.x, res.y, res.p, frac, "slip-threshold continuation", max_fraction=2.0 * frac,
                         rms=res.rms_residuals)
    c, res, rms, bc_res = best
    return RawSolution(
        case=case, t=res.x, y=res.y, p=res.p, sol=res.sol, residual_max=rms, bc_residual_max=bc_res, tol=tol,
        history=history, solve_s=time.perf_counter() - t0, rms_residuals=res.rms_residuals,
    )
