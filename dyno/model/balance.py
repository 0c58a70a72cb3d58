"""Global force, moment and power balances of a full-model solution (pure, no I/O).

Each contact arc is cut on the *span* side of its two ends, so the free body
is the arc plus whatever acts at the interfaces.  Sign conventions (derived
in docs/belt-model.md, "Balances"): the internal force of the belt is
``F = T t - Q n`` in a contact region (Q = dM/ds, the contact equations' shear)
and ``F = tau t + V n``, ``V = -EI_eff theta_ss``, in a span, with ``n`` the
tangent ``t`` turned +90 degrees; the bending moment is EI times the
curvature.  Steady equilibrium of an element is ``dF/ds + f = 0`` with ``f``
the sheave force per length on the belt; at an interface the belt receives
the point load ``P = F(upstream) - F(downstream)`` (the bending-shear jump:
both tension and direction are continuous there).

The ``corrected`` variant makes the shear continuous, so these jumps vanish
(computed anyway, and carried in the torques if they ever appear); the
``as_published`` model's zero-shear ends leave jumps nobody carries.

Power: input - output = friction dissipation + work of the normal force on
the sliding, i.e. the sheaves' forces do no net work on a belt that stores no
energy in steady state.
"""

from __future__ import annotations

import math

import numpy as np

# the state layout, the contact terms and RawSolution from equations, not bvp: bvp's boundary conditions
# use these balances
from dyno.model import equations as eq

_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(3)

# interface names: (pulley, end) -> the span on the other side and which of its ends
_PULLEYS = ("primary", "secondary")


def _gauss_nodes(t: np.ndarray):
    a, b = t[:-1], t[1:]
    half, mid = 0.5 * (b - a), 0.5 * (b + a)
    return (mid[:, None] + half[:, None] * _GAUSS_X[None, :]).ravel(), (half[:, None] * _GAUSS_W[None, :]).ravel()


def carries_point_loads(case: eq.Case) -> bool:
    return case.variant != "as_published"


def _span_ei_eff(case: eq.Case, length_m: float) -> float:
    # as published, the swapped L^2 terms make the span stiffness EI L^4 (module docstring of bvp)
    return case.ei_nm2 * length_m**4 if case.variant == "as_published" else case.ei_nm2


def _unit(angle):
    # np, not math: the boundary conditions' Jacobian evaluates these on complex (n, B) batches
    return np.array([np.cos(angle), np.sin(angle)])


def _cross(a, b):
    return a[0] * b[1] - a[1] * b[0]


def _pulley_geometry(case: eq.Case, p, which: str):
    if which == "primary":
        rows = (eq.P_T, eq.P_TH, eq.P_TH1, eq.P_TH2, eq.P_X, eq.P_X1)
        phi, radius, centre = p[eq.K_PHIP], case.r_primary_m, np.zeros(2)
        alpha0 = p[eq.K_CP]
    else:
        rows = (eq.S_T, eq.S_TH, eq.S_TH1, eq.S_TH2, eq.S_X, eq.S_X1)
        phi, radius, centre = p[eq.K_PHIS], case.r_secondary_m, np.array([case.centre_distance_m, 0.0])
        alpha0 = math.pi - p[eq.K_CS] - p[eq.K_PHIS]
    return rows, phi, radius, centre, alpha0


def _contact_end(case, y_end, p, which):
    """Internal force, bending moment and position (about the pulley centre) on the contact side of one end."""
    rows, phi, radius, _, _ = _pulley_geometry(case, p, which)
    t_n = y_end[rows[0]] * eq.TENSION_REF_N
    th, th1, th2 = y_end[rows[1]], y_end[rows[2]], y_end[rows[3]]
    x_m, x1_m = y_end[rows[4]] * eq.PENETRATION_REF_M, y_end[rows[5]] * eq.PENETRATION_REF_M
    q = eq.contact_shear(case, th, th1, th2, x_m, x1_m, radius, phi)
    kappa = np.cos(th) * (1.0 - th1 / phi) / (radius - x_m)
    return t_n, th, q, case.ei_nm2 * kappa, radius - x_m


def _span_end(case, y_end, p, span: str):
    rows = (eq.T_TAU, eq.T_V, eq.T_V1, eq.T_V2) if span == "tight" else (eq.L_TAU, eq.L_V, eq.L_V1, eq.L_V2)
    length = p[eq.K_LT] if span == "tight" else p[eq.K_LS]
    ei = _span_ei_eff(case, length)
    direction = y_end[rows[1]]
    shear = -ei * y_end[rows[3]] / length**2
    force = y_end[rows[0]] * eq.TENSION_REF_N * _unit(direction) + shear * _unit(direction + math.pi / 2)
    return force, ei * y_end[rows[2]] / length


def interface_loads(raw: eq.RawSolution) -> dict:
    """:func:`interface_loads_at_ends` of a solution."""
    return interface_loads_at_ends(raw.case, raw.y[:, 0], raw.y[:, -1], raw.p)


def interface_loads_at_ends(case: eq.Case, ya, yb, p) -> dict:
    """Per (pulley, end): span-side and contact-side force and moment, and the point load on the belt.

    Vectors in the drive frame (N), positions relative to the pulley centre (m).
    Pure and cheap: the boundary conditions call it (torque and axial-force levels), on single states or,
    for their Jacobian, on (n, B) batches of complex-stepped ones (every operation here is analytic).
    """
    # (pulley, end) -> (contact state column, span, span state column, span is upstream)
    table = {
        ("primary", "entry"): (ya, "tight", yb, True),
        ("primary", "exit"): (yb, "slack", ya, False),
        ("secondary", "entry"): (ya, "slack", yb, True),
        ("secondary", "exit"): (yb, "tight", ya, False),
    }
    out = {}
    for (which, end), (y_c, span, y_s, span_upstream) in table.items():
        _, phi, _, _, alpha0 = _pulley_geometry(case, p, which)
        alpha = alpha0 + (0.0 if end == "entry" else phi)
        t_n, th, q, moment_c, r_loc = _contact_end(case, y_c, p, which)
        psi = alpha + math.pi / 2 - th
        f_contact = t_n * _unit(psi) - q * _unit(psi + math.pi / 2)
        f_span, moment_s = _span_end(case, y_s, p, span)
        jump = f_span - f_contact if span_upstream else f_contact - f_span
        # Tension and direction are continuous (their own BCs): the point load is the normal part.
        n_hat = _unit(psi + math.pi / 2)
        normal_load = np.sum(jump * n_hat, axis=0) * n_hat
        out[(which, end)] = {
            "position_m": r_loc * _unit(alpha),
            "span_force_n": f_span,
            "span_moment_nm": moment_s,
            "contact_force_n": f_contact,
            "contact_moment_nm": moment_c,
            "point_load_n": normal_load if carries_point_loads(case) else np.zeros(2),
            "shear_jump_n": jump,
            "alpha_rad": alpha,
            "psi_rad": psi,
        }
    return out


def point_load_torque_nm(loads: dict, which: str) -> float:
    """Torque on the belt about the pulley centre from the point loads at its two ends."""
    return sum(_cross(loads[(which, e)]["position_m"], loads[(which, e)]["point_load_n"]) for e in ("entry", "exit"))


def _distributed(raw: eq.RawSolution, which: str):
    """Quadrature over one contact arc: force on the belt, its moment, friction dissipation, normal-force work."""
    case, p = raw.case, raw.p
    rows, phi, radius, _, alpha0 = _pulley_geometry(case, p, which)
    tq, w = _gauss_nodes(raw.t)
    y = raw.sol(tq)
    omega_s, g = eq.unpack_params(case, p)
    omega = case.omega_primary_rad_s if which == "primary" else omega_s
    t_n = y[rows[0]] * eq.TENSION_REF_N
    x_m, x1_m = y[rows[4]] * eq.PENETRATION_REF_M, y[rows[5]] * eq.PENETRATION_REF_M
    *_, ex = eq.contact_terms(case, t_n, y[rows[1]], y[rows[2]], y[rows[3]], x_m, x1_m, radius, phi, omega, g)
    gam = ex["sliding_angle_rad"]
    cos_g, sin_g = np.cos(gam), np.sin(gam)
    tb = math.tan(case.beta_rad) * cos_g
    cbs = 1.0 / np.sqrt(1.0 + tb * tb)
    press, mu, ds = ex["pressure_n_m"], ex["mu"], w * ex["arc_m"]
    f_out = 2.0 * press * (math.sin(case.beta_rad) - mu * cbs * cos_g)  # outward radial, per length
    f_circ = -2.0 * press * mu * cbs * sin_g  # along the pulley's motion, per length
    alpha = alpha0 + phi * tq
    e_out = np.vstack([np.cos(alpha), np.sin(alpha)])
    e_c = np.vstack([-np.sin(alpha), np.cos(alpha)])
    force = (e_out * f_out + e_c * f_circ) @ ds
    r_loc = radius - x_m
    v_r = ex["belt_speed_m_s"] * np.sin(y[rows[1]])
    return {
        "force_n": force,
        "moment_nm": float(np.sum(f_circ * r_loc * ds)),
        "friction_w": float(np.sum(2.0 * press * mu * cbs * ex["sliding_speed_m_s"] * ds)),
        "normal_work_w": float(-np.sum(2.0 * press * math.sin(case.beta_rad) * v_r * ds)),
        "omega_rad_s": omega,
    }


def balances(raw: eq.RawSolution) -> dict:
    """Force, moment (about each pulley centre) and power balances, each relative to its largest term.

    Returns ``{"force_rel", "moment_rel", "power_rel", "detail": {...}}``;
    force and moment are the worse of the two pulleys.
    """
    loads = interface_loads(raw)
    detail: dict = {"point_load_n": {}, "pulley": {}}
    force_rel = moment_rel = 0.0
    torque_on_belt = {}
    power_terms = {"friction_w": 0.0, "normal_work_w": 0.0}
    for which in _PULLEYS:
        dist = _distributed(raw, which)
        entry, exit_ = loads[(which, "entry")], loads[(which, "exit")]
        f_terms = [-entry["span_force_n"], exit_["span_force_n"], dist["force_n"], entry["point_load_n"],
                   exit_["point_load_n"]]
        f_sum = np.sum(f_terms, axis=0)
        f_scale = max(float(np.hypot(*v)) for v in f_terms)
        m_terms = [
            -(_cross(entry["position_m"], entry["span_force_n"]) + entry["span_moment_nm"]),
            _cross(exit_["position_m"], exit_["span_force_n"]) + exit_["span_moment_nm"],
            dist["moment_nm"],
            _cross(entry["position_m"], entry["point_load_n"]),
            _cross(exit_["position_m"], exit_["point_load_n"]),
        ]
        m_sum = sum(m_terms)
        m_scale = max(abs(v) for v in m_terms)
        torque = dist["moment_nm"] + m_terms[3] + m_terms[4]
        torque_on_belt[which] = (torque, dist["omega_rad_s"])
        # Point loads are normal to the belt, so on the sliding they do minus their work on the pulley.
        point_work = 0.0
        for end in (entry, exit_):
            e_c = _unit(end["alpha_rad"] + math.pi / 2)
            surface_speed = float(np.hypot(*end["position_m"])) * dist["omega_rad_s"]
            point_work += float(np.dot(end["point_load_n"], e_c)) * surface_speed
        power_terms["friction_w"] += dist["friction_w"]
        power_terms["normal_work_w"] += dist["normal_work_w"] + point_work
        force_rel = max(force_rel, float(np.hypot(*f_sum)) / f_scale)
        moment_rel = max(moment_rel, abs(m_sum) / m_scale)
        for end_name, end in (("entry", entry), ("exit", exit_)):
            detail["point_load_n"][f"{which}_{end_name}"] = float(np.hypot(*end["shear_jump_n"]))
        detail["pulley"][which] = {"force_residual_n": float(np.hypot(*f_sum)), "moment_residual_nm": float(m_sum),
                                   "torque_on_belt_nm": float(torque)}
    p_in = torque_on_belt["primary"][0] * torque_on_belt["primary"][1]
    p_out = -torque_on_belt["secondary"][0] * torque_on_belt["secondary"][1]
    p_terms = [p_in, p_out, power_terms["friction_w"], power_terms["normal_work_w"]]
    p_res = p_in - p_out - power_terms["friction_w"] - power_terms["normal_work_w"]
    detail["power_w"] = {"input": p_in, "output": p_out, **power_terms, "residual": p_res}
    detail["point_loads_carried"] = carries_point_loads(raw.case)
    return {
        "force_rel": force_rel,
        "moment_rel": moment_rel,
        "power_rel": abs(p_res) / max(abs(v) for v in p_terms),
        "detail": detail,
    }
