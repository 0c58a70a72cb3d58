"""Boundary conditions of the full model (34 = 26 states + 8 parameters; see ``equations.py``).

Zero penetration at every contact end (5.51); eq 3.24 at each entry (5.52,
5.53); zero torque and axial force at the primary entry (5.61, 5.62);
continuity of tension, direction, curvature and position between regions;
at the four contact ends the shear: continuous into the span (corrected;
zero on the pulley side as published, 5.43-5.46); and the operating
point (primary torque, plus the slack tension or the primary axial force).
"""

from __future__ import annotations

import math

import numpy as np

from dyno.model import balance
from dyno.model.equations import (  # the state layout and scales
    AXIAL_REF_N,
    K_CP,
    K_CS,
    K_LS,
    K_LT,
    K_PHIP,
    K_PHIS,
    L_TAU,
    L_V2,
    L_V,
    L_V1,
    L_XP,
    L_YP,
    PENETRATION_REF_M,
    POSITION_BC_REF_M,
    P_A,
    P_M,
    P_T,
    P_TH,
    P_TH1,
    P_TH2,
    P_X,
    P_X1,
    S_T,
    S_TH,
    S_TH1,
    S_TH2,
    S_X,
    S_X1,
    TENSION_REF_N,
    TORQUE_REF_NM,
    T_TAU,
    T_V,
    T_V1,
    T_V2,
    T_XP,
    T_YP,
)
from dyno.model.equations import Case


def make_bc(case: Case):
    """The ``bc(ya, yb, p)`` of solve_bvp for ``case`` (34 residuals, O(1) scaled)."""
    r_s, r_p, lc = case.r_secondary_m, case.r_primary_m, case.centre_distance_m
    published = case.variant == "as_published"

    def bc(ya, yb, p):
        phi_s, phi_p, c_s, c_p, l_t, l_s = p[K_PHIS], p[K_PHIP], p[K_CS], p[K_CP], p[K_LT], p[K_LS]
        xs0, xs1 = ya[S_X] * PENETRATION_REF_M, yb[S_X] * PENETRATION_REF_M
        xp0, xp1 = ya[P_X] * PENETRATION_REF_M, yb[P_X] * PENETRATION_REF_M
        # Entry/exit directions w.r.t. +x (5.21-5.24; 5.23 with -theta_S1).
        e_st = math.pi / 2 - c_s - yb[S_TH]  # (np functions below: bc_jac evaluates on complex batches)
        e_ss = 3 * math.pi / 2 - c_s - phi_s - ya[S_TH]
        e_pt = c_p - math.pi / 2 - ya[P_TH]
        e_ps = c_p + phi_p - 3 * math.pi / 2 - yb[P_TH]
        # Contact end points (5.17-5.20 with the code's labels).
        pts = {
            "st": (lc - r_s * np.cos(c_s), r_s * np.sin(c_s)),
            "ss": (lc - r_s * np.cos(c_s + phi_s), r_s * np.sin(c_s + phi_s)),
            "pt": (r_p * np.cos(c_p), r_p * np.sin(c_p)),
            "ps": (r_p * np.cos(c_p + phi_p), r_p * np.sin(c_p + phi_p)),
        }

        def curvature(th, th1, x_m, radius, phi):
            return np.cos(th) / (radius - x_m) * (1.0 - th1 / phi)

        def span_shear(v2, length, th, radius, phi):
            """Span-side shear V in the units of ``shear``: corrected, the shear is continuous (Q = -V).

            The contact is an elastic foundation (finite pressure k x): it cannot supply the point
            load a jump would need (docs/belt-model.md, Balances).  As published: zero shear.
            """
            if published:
                return 0.0
            v = -case.ei_nm2 * v2 / length**2
            return v * phi * phi * radius * radius / (case.ei_nm2 * np.cos(th) ** 2)

        def shear(th2, x1_scaled, radius, phi, th=0.0, th1=0.0, x_scaled=0.0):
            x1 = x1_scaled * PENETRATION_REF_M
            if published:
                return -th2 + x1 / radius
            # exact dM/ds = 0, times Phi (R - x)/(EI cos(theta)): -th2 + Phi x1/R when linearised
            w = 1.0 - th1 / phi
            return -np.tan(th) * th1 * w * phi - th2 + phi * w * x1 / (radius - x_scaled * PENETRATION_REF_M)

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
            (ya[S_X1] * PENETRATION_REF_M + phi_s * (r_s - xs0) * np.tan(ya[S_TH])) / PENETRATION_REF_M,
            yb[P_M] + (case.torque_nm - torque_points) / TORQUE_REF_NM,
            level,
            ya[P_X],
            yb[P_X],
            ya[P_M],
            (ya[P_X1] * PENETRATION_REF_M + phi_p * (r_p - xp0) * np.tan(ya[P_TH])) / PENETRATION_REF_M,
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
            # shear at the contact ends: continuous (corrected) or zero (5.43-5.46, as published;
            # its bc(26) reads the entry x').
            shear(ya[S_TH2], ya[S_X1], r_s, phi_s, ya[S_TH], ya[S_TH1], ya[S_X])
            + span_shear(yb[L_V2], l_s, ya[S_TH], r_s, phi_s),
            shear(yb[S_TH2], yb[S_X1], r_s, phi_s, yb[S_TH], yb[S_TH1], yb[S_X])
            + span_shear(ya[T_V2], l_t, yb[S_TH], r_s, phi_s),
            shear(ya[P_TH2], ya[P_X1], r_p, phi_p, ya[P_TH], ya[P_TH1], ya[P_X])
            + span_shear(yb[T_V2], l_t, ya[P_TH], r_p, phi_p),
            shear(yb[P_TH2], ya[P_X1] if published else yb[P_X1], r_p, phi_p, yb[P_TH], yb[P_TH1], yb[P_X])
            + span_shear(ya[L_V2], l_s, yb[P_TH], r_p, phi_p),
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
        return np.array(np.broadcast_arrays(*res))

    return bc


#: Complex step of :func:`make_bc_jac`: any h far below the states' O(1) scales gives the derivative to rounding.
COMPLEX_STEP = 1e-30


def make_bc_jac(case: Case, bc=None):
    r"""``bc_jac(ya, yb, p)`` for solve_bvp: the boundary conditions' exact Jacobian, in one vectorised call.

    The conditions are algebraic and analytic in every argument, so for each argument z_j
    (the 26 states at each end, then the 8 parameters; N = 60 columns)

    .. math:: \partial bc_i/\partial z_j = \operatorname{Im}\, bc_i(z + i h e_j) / h

    exactly up to rounding (complex-step differentiation, Squire & Trapp 1998: no difference is taken,
    so h can be 1e-30 and there is no truncation or cancellation error, unlike a forward difference).
    All 60 columns are one call of ``bc`` on a (n, 60) complex batch: ~1/60 of the Python overhead of
    scipy's column-by-column estimate (which called ``bc`` 64 times per Jacobian).
    """
    bc = make_bc(case) if bc is None else bc
    h = COMPLEX_STEP

    def bc_jac(ya, yb, p):
        n, k = ya.size, p.size
        cols = 2 * n + k
        za = np.repeat(np.asarray(ya, dtype=complex)[:, None], cols, axis=1)
        zb = np.repeat(np.asarray(yb, dtype=complex)[:, None], cols, axis=1)
        zp = np.repeat(np.asarray(p, dtype=complex)[:, None], cols, axis=1)
        i_n, i_k = np.arange(n), np.arange(k)
        za[i_n, i_n] += 1j * h
        zb[i_n, n + i_n] += 1j * h
        zp[i_k, 2 * n + i_k] += 1j * h
        jac = np.imag(bc(za, zb, zp)) / h
        return jac[:, :n], jac[:, n:2 * n], jac[:, 2 * n:]

    return bc_jac



def contact_points(case: Case, p):
    r_s, r_p, lc = case.r_secondary_m, case.r_primary_m, case.centre_distance_m
    c_s, phi_s, c_p, phi_p = p[K_CS], p[K_PHIS], p[K_CP], p[K_PHIP]
    return {
        "st": complex(lc - r_s * math.cos(c_s), r_s * math.sin(c_s)),
        "ss": complex(lc - r_s * math.cos(c_s + phi_s), r_s * math.sin(c_s + phi_s)),
        "pt": complex(r_p * math.cos(c_p), r_p * math.sin(c_p)),
        "ps": complex(r_p * math.cos(c_p + phi_p), r_p * math.sin(c_p + phi_p)),
    }
