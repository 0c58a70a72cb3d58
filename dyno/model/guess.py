"""Initial guess from geometry, warm-start transfer, re-meshing and the homotopy between cases."""

from __future__ import annotations

import math
from dataclasses import fields, replace

import numpy as np

from dyno.model import geometry
from dyno.model.boundary import contact_points
from dyno.model.equations import (  # the state layout and scales
    AXIAL_REF_N,
    CREEP_SCALE,
    K_CP,
    K_CS,
    K_G,
    K_LS,
    K_LT,
    K_PHIP,
    K_PHIS,
    K_WS,
    L_TAU,
    L_V,
    L_V1,
    L_V2,
    L_XP,
    L_YP,
    N_PARAMS,
    N_STATES,
    PENETRATION_REF_M,
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
from dyno.model.equations import Case, belt_speed, mass_flow_for_speed, unpack_params



def _smoothstep(t):
    return t * t * (3.0 - 2.0 * t)


def span_bending_length_m(case: Case, tension_n: float) -> float:
    ei_eff = case.ei_nm2
    if case.variant == "as_published":
        ei_eff = case.ei_nm2 * 0.2**4  # swapped L^2 terms: EI L^4 with L ~ the span length
    return math.sqrt(ei_eff / max(tension_n, 1.0))


def initial_guess(case: Case, n_nodes: int = 301):
    """Geometric initial guess ``(t, y, p)``; needs no starting solution."""
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
    d_pt = span_bending_length_m(case, t_tight) / r_p
    d_ps = span_bending_length_m(case, t_slack) / r_p
    d_st = span_bending_length_m(case, t_tight) / r_s
    d_ss = span_bending_length_m(case, t_slack) / r_s
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
    omega_s_old, g_old = unpack_params(old, p)
    # primary: the point of least slip (the adhesion zone, if any)
    t_p = y[P_T] * TENSION_REF_N
    x_p = y[P_X] * PENETRATION_REF_M
    v_old = belt_speed(old, g_old, t_p)
    slip = np.abs(v_old * np.cos(y[P_TH]) - (old.r_primary_m - x_p) * old.omega_primary_rad_s)
    j = int(np.argmin(slip))
    surf_shift = (new.r_primary_m - x_p[j]) * new.omega_primary_rad_s - (old.r_primary_m - x_p[j]) * old.omega_primary_rad_s
    v_new = v_old[j] + surf_shift / math.cos(y[P_TH, j])
    if not (math.isfinite(v_new) and v_new > 0):
        return
    g_new = mass_flow_for_speed(new, v_new, t_p[j])
    p[K_G] = (g_new / new.g_ref - 1.0) / CREEP_SCALE
    # secondary: keep the sliding speed at its point of least slip
    t_s = y[S_T] * TENSION_REF_N
    x_s = y[S_X] * PENETRATION_REF_M
    vs_old = belt_speed(old, g_old, t_s)
    slip_s = vs_old * np.cos(y[S_TH]) - (old.r_secondary_m - x_s) * omega_s_old
    k = int(np.argmin(np.abs(slip_s)))
    vs_new = belt_speed(new, g_new, t_s[k])
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
            return span_bending_length_m(case, tension) / radius

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
    old_pts, new_pts = contact_points(old, p), contact_points(new, p)
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



def interp_case(a: Case, b: Case, s: float) -> Case:
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
