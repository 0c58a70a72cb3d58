r"""Equations of the full steady model (Messick 2018): state layout, scales, the case, the right-hand sides.

Split from ``bvp.py`` (which solves them); the boundary conditions are in
``boundary.py``, the initial guess and continuation helpers in ``guess.py``.


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
That is the ``as_published`` variant.  ``corrected`` carries the exact
:math:`Q = dM/ds` of :math:`M = EI\cos\theta(1 - \theta')/(R - x)` (3.32) in
:math:`\hat T'` and its exact derivative :math:`\hat Q' = a + b\hat\theta'''`
in the normal balance (:func:`exact_shear`), solved for the third derivative;
linearised, the factor is R where 3.40/3.41 print (R + 2x).
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
(5.27-5.34, exit/entry labels as in the code); the shear at the four contact
ends: continuous into the spans (corrected: the elastic contact cannot take a
point load; docs/belt-model.md, Balances) or zero on the pulley side (5.43-5.46,
as published); and the
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

import math
from dataclasses import dataclass, field

import numpy as np

from dyno.model import geometry
from dyno.model.params import VARIANTS, ModelParams, OperatingPoint, bad_input

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


@dataclass
class RawSolution:
    """What solve_bvp returned for one case, plus the continuation history (here, beside the state layout, so
    the balances can name it without importing the solver)."""

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


def unpack_params(case: Case, p):
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
        omega_s, g = unpack_params(case, p)
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
BLOCKS = (
    (S_T, S_TH, S_TH1, S_TH2, S_X, S_X1),
    (P_T, P_TH, P_TH1, P_TH2, P_X, P_X1, P_M, P_A),
    (T_TAU, T_V, T_V1, T_V2, T_XP, T_YP),
    (L_TAU, L_V, L_V1, L_V2, L_XP, L_YP),
)
_BLOCK_OF_ROW = np.empty(N_STATES, dtype=int)
for _b, _rows in enumerate(BLOCKS):
    _BLOCK_OF_ROW[list(_rows)] = _b
# Parameter groups with disjoint row supports (K_CS, K_CP do not enter the rhs).
_PARAM_GROUPS = ((K_WS, K_PHIP, K_LT, K_LS), (K_PHIS,), (K_G,))
_PARAM_ROWS = {
    K_WS: BLOCKS[0], K_PHIS: BLOCKS[0], K_PHIP: BLOCKS[1], K_LT: BLOCKS[2], K_LS: BLOCKS[3],
    K_G: BLOCKS[0] + BLOCKS[1],
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
    n_groups = max(len(b) for b in BLOCKS)
    n_eval = 1 + n_groups + len(_PARAM_GROUPS)

    def fun_jac(t, y, p):
        n, m = y.shape
        h_y = _EPS_SQRT * (1.0 + np.abs(y))
        h_p = _EPS_SQRT * (1.0 + np.abs(p))
        y_all = np.tile(y, (1, n_eval))
        p_all = np.repeat(p[:, None], n_eval * m, axis=1)
        for j in range(n_groups):
            cols = slice((1 + j) * m, (2 + j) * m)
            for rows in BLOCKS:
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
            for rows in BLOCKS:
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



def belt_speed(case: Case, g, t_n):
    return g * (t_n + case.ea_n) / (case.ea_n * case.mass_kg_m - g * g)


def mass_flow_for_speed(case: Case, v, t_n):
    """Inverse of :func:`belt_speed` in G (the root of V G^2 + (T + EA) G - V EA m = 0)."""
    b = t_n + case.ea_n
    return (-b + math.sqrt(b * b + 4.0 * v * v * case.ea_n * case.mass_kg_m)) / (2.0 * v)
