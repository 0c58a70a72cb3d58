"""Post-processing of a full-model solution: summary figures and profiles.

Integrated quantities the BVP does not carry as states (secondary torque and
axial force, unstretched lengths, resultant locations) are computed by
3-point Gauss-Legendre quadrature on every mesh interval of the collocation
interpolant, which is exact for the cubic pieces up to the non-linearity of
the integrands.

Conventions: the primary is the driver; torques are positive magnitudes
(input on the primary, output on the secondary); tensions are tractive
(T = F - G V) unless named ``effective``; angles of inclination are positive
when the belt unseats.  Resultant locations follow thesis eqs 6.3-6.6 and are
relative to each pulley centre in the drive frame (primary at the origin,
secondary on the +x axis, tight span on top).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dyno.model import balance, bvp, equations

AS_PUBLISHED_WARNING = (
    "as_published reproduces the thesis's code, which is out of energy balance: bending energy vanishes where "
    "the pulley (EI) meets the span (EI*L^4), so most of its loss (see power_w.residual) is an artefact; its "
    "efficiency is not a prediction (docs/belt-model.md, Balances)"
)

_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(3)


def _gauss_nodes(t: np.ndarray):
    """Quadrature nodes and weights covering [0, 1] interval by interval."""
    a, b = t[:-1], t[1:]
    half = 0.5 * (b - a)
    mid = 0.5 * (b + a)
    nodes = (mid[:, None] + half[:, None] * _GAUSS_X[None, :]).ravel()
    weights = (half[:, None] * _GAUSS_W[None, :]).ravel()
    return nodes, weights


def _contact_eval(case: equations.Case, y: np.ndarray, p: np.ndarray, which: str):
    omega_s, g = equations.unpack_params(case, p)
    if which == "primary":
        idx = (equations.P_T, equations.P_TH, equations.P_TH1, equations.P_TH2, equations.P_X, equations.P_X1)
        radius, phi, omega = case.r_primary_m, p[equations.K_PHIP], case.omega_primary_rad_s
    else:
        idx = (equations.S_T, equations.S_TH, equations.S_TH1, equations.S_TH2, equations.S_X, equations.S_X1)
        radius, phi, omega = case.r_secondary_m, p[equations.K_PHIS], omega_s
    t_n = y[idx[0]] * equations.TENSION_REF_N
    x_m = y[idx[4]] * equations.PENETRATION_REF_M
    x1_m = y[idx[5]] * equations.PENETRATION_REF_M
    d_t, d_th3, x2, d_m, d_a, extras = equations.contact_terms(
        case, t_n, y[idx[1]], y[idx[2]], y[idx[3]], x_m, x1_m, radius, phi, omega, g
    )
    return t_n, x_m, d_m, d_a, extras, g


def _effective_tension(case: equations.Case, t_n, g):
    """Belt tension F from the tractive tension (eq 3.10)."""
    m, ea = case.mass_kg_m, case.ea_n
    return (t_n + g * g / m) / (1.0 - g * g / (ea * m))


@dataclass
class BeltSolution:
    """A converged full-model solution with its summary and profiles."""

    raw: equations.RawSolution
    variant: str
    summary: dict = field(default_factory=dict)

    @property
    def case(self) -> equations.Case:
        return self.raw.case

    def as_dict(self) -> dict:
        return dict(self.summary)

    def profiles(self, n_points: int = 400) -> dict:
        """Profiles along each region on ``n_points`` evenly spaced normalised points.

        Contact regions: wrap angle, tractive tension, inclination, penetration,
        sliding speed and angle, axial pressure (force per belt length on the
        sheave pair, k x / 2).  Spans: arc length, tractive tension, direction,
        x and y.
        """
        raw = self.raw
        case, p = raw.case, raw.p
        t = np.linspace(0.0, 1.0, n_points)
        y = raw.sol(t)
        out = {}
        for which, phi_idx, th_i in (("primary", equations.K_PHIP, equations.P_TH), ("secondary", equations.K_PHIS, equations.S_TH)):
            t_n, x_m, d_m, d_a, ex, _ = _contact_eval(case, y, p, which)
            out[which] = {
                "wrap_angle_deg": np.degrees(p[phi_idx] * t),
                "tension_n": t_n,
                "inclination_deg": np.degrees(y[th_i]),
                "penetration_m": x_m,
                "sliding_speed_m_s": ex["sliding_speed_m_s"],
                "sliding_angle_deg": np.degrees(ex["sliding_angle_rad"]) % 360.0,
                "friction_coefficient": ex["mu"],
                "axial_pressure_n_m": 0.5 * case.k_n_m2 * x_m,
            }
        for which, l_idx, rows in (
            ("tight_span", equations.K_LT, (equations.T_TAU, equations.T_V, equations.T_XP, equations.T_YP)),
            ("slack_span", equations.K_LS, (equations.L_TAU, equations.L_V, equations.L_XP, equations.L_YP)),
        ):
            length = p[l_idx]
            out[which] = {
                "arc_length_m": length * t,
                "tension_n": y[rows[0]] * equations.TENSION_REF_N,
                "direction_deg": np.degrees(y[rows[1]]),
                "x_m": y[rows[2]] * length,
                "y_m": y[rows[3]] * length,
            }
        return out


def postprocess(raw: equations.RawSolution, pitch_length_m: float | None = None) -> BeltSolution:
    """Summary figures of a solved case (see module docstring for conventions)."""
    case, p, y_mesh = raw.case, raw.p, raw.y
    tq, w = _gauss_nodes(raw.t)
    y = raw.sol(tq)
    omega_s, g = equations.unpack_params(case, p)
    ratio_geom = case.r_secondary_m / case.r_primary_m

    res = {}
    for which, phi_idx, c_idx in (("primary", equations.K_PHIP, equations.K_CP), ("secondary", equations.K_PHIS, equations.K_CS)):
        t_n, x_m, d_m, d_a, ex, _ = _contact_eval(case, y, p, which)
        radius = case.r_primary_m if which == "primary" else case.r_secondary_m
        phi, c = p[phi_idx], p[c_idx]
        # Polar angle of each point about its own centre (eqs 6.5, 6.6).
        ang = c + phi * tq if which == "primary" else math.pi - c - phi + phi * tq
        r_loc = radius - x_m
        axial = float(np.sum(w * d_a))
        xbar = float(np.sum(w * d_a * r_loc * np.cos(ang))) / axial
        ybar = float(np.sum(w * d_a * r_loc * np.sin(ang))) / axial
        f_eff = _effective_tension(case, t_n, g)
        unstretched = float(np.sum(w * ex["arc_m"] / (1.0 + f_eff / case.ea_n)))
        # Minimum sliding speed: on the dense quadrature nodes and the mesh.
        _, _, _, _, ex_mesh, _ = _contact_eval(case, y_mesh, p, which)
        res[which] = {
            "torque_nm": float(np.sum(w * d_m)),
            "axial_force_n": axial,
            "resultant_m": (xbar, ybar),
            "unstretched_m": unstretched,
            "min_sliding_m_s": float(min(ex["sliding_speed_m_s"].min(), ex_mesh["sliding_speed_m_s"].min())),
            "adhesion_fraction": float(np.sum(w[ex["sliding_speed_m_s"] < case.slip_threshold_m_s])),
            "max_penetration_m": float(max(x_m.max(), y_mesh[equations.P_X if which == "primary" else equations.S_X].max() * equations.PENETRATION_REF_M)),
        }
    spans = {}
    for which, l_idx, tau_i in (("tight", equations.K_LT, equations.T_TAU), ("slack", equations.K_LS, equations.L_TAU)):
        tau = y[tau_i] * equations.TENSION_REF_N
        f_eff = _effective_tension(case, tau, g)
        spans[which] = float(np.sum(w * p[l_idx] / (1.0 + f_eff / case.ea_n)))

    # Point loads at the contact ends (shear jumps) would add to the pulleys' torques; the corrected
    # variant makes the shear continuous, so they vanish there (computed anyway: the balances check it).
    loads = balance.interface_loads(raw)
    torque_in = -float(y_mesh[equations.P_M, -1] * equations.TORQUE_REF_NM) + balance.point_load_torque_nm(loads, "primary")
    torque_out = res["secondary"]["torque_nm"] - balance.point_load_torque_nm(loads, "secondary")
    bal = balance.balances(raw)
    eta_speed = omega_s / (case.omega_primary_rad_s * case.r_primary_m / case.r_secondary_m)
    eta_torque = (torque_out / torque_in) / ratio_geom
    t_tight = float(y_mesh[equations.P_T, 0] * equations.TENSION_REF_N)
    t_slack = float(y_mesh[equations.P_T, -1] * equations.TENSION_REF_N)
    unstretched_total = sum(r["unstretched_m"] for r in res.values()) + sum(spans.values())
    a_p = float(y_mesh[equations.P_A, -1] * equations.AXIAL_REF_N)
    a_s = res["secondary"]["axial_force_n"]

    def moment(which, force):
        xb, yb = res[which]["resultant_m"]
        return force * math.hypot(xb, yb)

    summary = {
        "variant": case.variant,
        "state": "steady",
        "converged": True,
        "residual_max": raw.residual_max,
        "bc_residual_max": raw.bc_residual_max,
        "tol": raw.tol,
        "mesh_nodes": int(raw.t.size),
        "continuation_steps": len(raw.history),
        "slip_threshold_m_s": case.slip_threshold_m_s,
        "boundary_condition": case.bc,
        "ratio": ratio_geom,
        "radius_m": {"primary": case.r_primary_m, "secondary": case.r_secondary_m},
        "primary_speed_rpm": case.omega_primary_rad_s * 60.0 / (2 * math.pi),
        "secondary_speed_rpm": omega_s * 60.0 / (2 * math.pi),
        "wrap_deg": {"primary": math.degrees(p[equations.K_PHIP]), "secondary": math.degrees(p[equations.K_PHIS])},
        "orientation_deg": {"primary": math.degrees(p[equations.K_CP]), "secondary": math.degrees(p[equations.K_CS])},
        "inclination_deg": {
            "primary_entry": math.degrees(y_mesh[equations.P_TH, 0]),
            "primary_exit": math.degrees(y_mesh[equations.P_TH, -1]),
            "secondary_entry": math.degrees(y_mesh[equations.S_TH, 0]),
            "secondary_exit": math.degrees(y_mesh[equations.S_TH, -1]),
        },
        "span_tension_n": {"tight": t_tight, "slack": t_slack},
        "span_tension_range_n": {
            "tight": [float(y_mesh[equations.T_TAU].min() * 100), float(y_mesh[equations.T_TAU].max() * 100)],
            "slack": [float(y_mesh[equations.L_TAU].min() * 100), float(y_mesh[equations.L_TAU].max() * 100)],
        },
        "span_length_m": {"tight": float(p[equations.K_LT]), "slack": float(p[equations.K_LS])},
        "mass_flow_kg_s": g,
        "torque_nm": {"primary": torque_in, "secondary": torque_out},
        "axial_force_n": {"primary": a_p, "secondary": a_s},
        "axial_resultant_m": {k: list(v["resultant_m"]) for k, v in res.items()},
        "binding_moment_nm": {"primary": moment("primary", a_p), "secondary": moment("secondary", a_s)},
        "efficiency": {"speed": eta_speed, "torque": eta_torque, "overall": eta_speed * eta_torque},
        "min_sliding_speed_m_s": {k: v["min_sliding_m_s"] for k, v in res.items()},
        "adhesion_fraction": {k: v["adhesion_fraction"] for k, v in res.items()},
        "max_penetration_m": {k: v["max_penetration_m"] for k, v in res.items()},
        "unstretched_length_m": unstretched_total,
        "pitch_length_m": pitch_length_m,
        "solve_s": raw.solve_s,
        "balance": {k: bal[k] for k in ("force_rel", "moment_rel", "power_rel")},
        "power_w": bal["detail"]["power_w"],
        "interface_point_load_n": {**bal["detail"]["point_load_n"], "carried": bal["detail"]["point_loads_carried"]},
    }
    if case.variant == "as_published":
        summary["warning"] = AS_PUBLISHED_WARNING
    return BeltSolution(raw=raw, variant=case.variant, summary=summary)


def solve_point(
    params=None,
    op=None,
    *,
    variant: str = "corrected",
    slip_threshold_m_s: float = 1e-4,
    tol: float = 1e-3,
    nodes: int = 200,
    guess: BeltSolution | None = None,
    time_limit_s: float = 120.0,
    keep_mesh_below: int = 0,
    friction_corner: float = 0.0,
    max_nodes: int = 8000,
    log=None,
) -> BeltSolution:
    """Solve the full model at one operating point.

    Parameters
    ----------
    params, op : ModelParams, OperatingPoint
        Default to the thesis's Table 6.1 case.
    variant : {"corrected", "as_published"}
    slip_threshold_m_s : float
        Slip speed below which the friction coefficient falls linearly to zero
        (a modelling parameter; report it with the results).
    tol : float
        solve_bvp tolerance (relative collocation residual and BC residual on
        O(1)-scaled states).
    nodes : int
        Nodes of the geometric initial guess (and of each re-mesh between continuation steps where the
        mesh is not equidistributed from the last residuals).
    guess : BeltSolution, optional
        A solution at a nearby point: warm start by homotopy in the physical
        parameters instead of continuation from the geometric guess.
    max_nodes : int
        Mesh-size limit of each solve_bvp call (bounds the time of one step).
    friction_corner : float
        0 (default) keeps the thesis's sharp viscous-Coulomb corner; e.g. 0.2
        rounds it (C-infinity), about halving the mesh and the run time for
        a change in the outputs below 1e-3 relative (see the benchmark).

    Raises
    ------
    DidNotConverge
        With the case, the continuation step and the last residual.
    ConfigError
        For inputs outside the feasible range.
    """
    from dyno.model.params import TABLE_6_1, TABLE_6_1_POINT

    params = TABLE_6_1 if params is None else params
    op = TABLE_6_1_POINT if op is None else op
    case = equations.make_case(params, op, variant, slip_threshold_m_s)
    if friction_corner:
        from dataclasses import replace as _replace

        case = _replace(case, friction_corner=float(friction_corner))
    raw = bvp.solve_case(
        case, guess=None if guess is None else guess.raw, tol=tol, nodes=nodes, time_limit_s=time_limit_s, keep_mesh_below=keep_mesh_below, max_nodes=max_nodes, log=log
    )
    return postprocess(raw, params.belt.pitch_length_m)
