r"""Full steady model of the thesis (Messick 2018, Sections 3 and 5): solve driver.

The model is split along its seams: ``equations.py`` (state layout, scales,
``Case``, contact and span right-hand sides, the coloured Jacobian; the
equations are written out in its docstring), ``boundary.py`` (the 34
boundary conditions), ``guess.py`` (geometric initial guess, warm-start
transfer, re-meshing, homotopy), ``collocation.py`` (scipy's ``solve_bvp``
with our linear algebra, in a private copy of its module).  This module
solves: continuation from the geometric guess (in the slip threshold, and
from equal radii in the radii and torque when the guess fails), warm starts,
and the checks of every result.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from dyno.errors import DidNotConverge, GrossSlip
from dyno.model import geometry
from dyno.model.boundary import make_bc, make_bc_jac
from dyno.model.collocation import solve_bvp_fast
from dyno.model.equations import (AXIAL_REF_N, CREEP_SCALE, Case, K_LS, K_LT, K_PHIP, K_PHIS, K_WS, L_TAU,
                                  PENETRATION_REF_M, P_A, P_T, P_TH, P_X, S_T, S_TH, S_X, TENSION_REF_N, T_TAU,
                                  make_fun, make_fun_jac)
from dyno.model.equations import RawSolution, belt_speed, unpack_params
from dyno.model.guess import interp_case, equidistributed_mesh, initial_guess, remesh, transfer_guess


# Largest slip-threshold step, in nominal steps (x0.4 each): steps grown beyond it below ~1e-3 m/s fail and
# are halved (docs/measurements/2026-12-06-docstring-history.md).
SLIP_STEP_GROWTH = 1.0
# Tolerance of the continuation's intermediate solves: they only carry the solution to the next step; the
# target is then solved again to ``tol`` on a mesh equidistributed from its own residual (``polish``).  The
# final solution does not depend on the path beyond the discretisation's own error: Table 6.1 at tol 1e-3
# and 1e-4 agrees to 1e-7 in efficiency and clamp forces, and the 14-case cold grid to 8e-7 of the
# all-at-tol march (tests/model/test_solve_speed.py).  A looser tolerance costs less CPU (fewer, smaller meshes
# on the way).
CONTINUATION_TOL = 5e-2
MIN_STEP_NODES = 600
STEP_NODE_FACTOR = 3.0
FINAL_FRACTION = 0.25
POLISH = True


@dataclass
class StepRecord:
    step: int
    slip_threshold_m_s: float
    status: int
    residual_max: float
    nodes: int
    seconds: float
    what: str = ""


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



def _slip_diagnosis(case: Case, y: np.ndarray, p: np.ndarray) -> str:
    """How close the last converged solution of a stalled continuation was to gross slip.

    A pulley whose belt slides everywhere by much more than v_th is near its
    torque capacity: past it there is no steady solution (the capstan/Gerbert
    bound on the tension ratio with the arched, shrinking wrap), so a stall
    there is the physics, not the solver.
    """
    from dyno.model.capstan import max_tension_ratio

    try:
        omega_s, g = unpack_params(case, p)
        parts = []
        for name, i_t, i_th, i_x, k_phi, radius, omega in (
            ("primary", P_T, P_TH, P_X, K_PHIP, case.r_primary_m, case.omega_primary_rad_s),
            ("secondary", S_T, S_TH, S_X, K_PHIS, case.r_secondary_m, omega_s),
        ):
            t_n = y[i_t] * TENSION_REF_N
            v = belt_speed(case, g, t_n)
            x_m = y[i_x] * PENETRATION_REF_M
            slip = np.hypot(v * np.sin(y[i_th]), v * np.cos(y[i_th]) - (radius - x_m) * omega)
            use = t_n.max() / t_n.min() / max_tension_ratio(p[k_phi], case.mu, case.beta_rad)
            gross = slip.min() > 100 * case.slip_threshold_m_s and use > 0.5
            parts.append(f"{name}: min sliding {slip.min():.3g} m/s, tension ratio at {100 * use:.0f} % of its "
                         f"capstan bound{' - approaching gross slip, no steady solution beyond' if gross else ''}")
        return f" [last converged point ({case.name()}): " + "; ".join(parts) + "]"
    except Exception:  # the diagnosis must never hide the failure itself
        return ""


def _pulleys_at_bound(case: Case, y: np.ndarray, p: np.ndarray, share: float = 0.95) -> set:
    """Pulleys whose tension ratio uses at least ``share`` of their capstan/Gerbert bound."""
    from dyno.model.capstan import max_tension_ratio

    out = set()
    for name, i_t, k_phi in (("primary", P_T, K_PHIP), ("secondary", S_T, K_PHIS)):
        t_n = y[i_t]
        if t_n.min() > 0 and t_n.max() / t_n.min() >= share * max_tension_ratio(p[k_phi], case.mu, case.beta_rad):
            out.add(name)
    return out


def _at_least_as_heavy(target: Case, c: Case, at_bound: set = frozenset()) -> bool:
    """The target asks at least as much of the belt as ``c``: torque >=, tension level <=, and the same
    radii, or (only the primary at its bound) a primary radius <= (a smaller driver under the same
    load has a larger tension difference M/R and a shorter wrap).

    Past gross slip at ``c`` then means past it at the target too.
    """
    if target.bc != c.bc:
        return False
    same_radii = (math.isclose(target.r_primary_m, c.r_primary_m, rel_tol=1e-9)
                  and math.isclose(target.r_secondary_m, c.r_secondary_m, rel_tol=1e-9))
    smaller_driver = at_bound == {"primary"} and target.r_primary_m <= c.r_primary_m * (1 + 1e-9)
    if not (same_radii or smaller_driver):
        return False
    level = "slack_tension_n" if target.bc == "slack_tension" else "axial_force_n"
    tiny = 1e-9
    return target.torque_nm >= c.torque_nm * (1 - tiny) and getattr(target, level) <= getattr(c, level) * (1 + tiny)


def _solve_once(case: Case, t, y, p, tol: float, max_nodes: int):
    fun, bc = make_fun(case), make_bc(case)
    fun_jac, bc_jac = make_fun_jac(case, fun), make_bc_jac(case, bc)
    with np.errstate(all="ignore"):
        res = solve_bvp_fast(fun, bc, t, y, p, tol=tol, max_nodes=max_nodes, bc_tol=tol, fun_jac=fun_jac,
                             bc_jac=bc_jac)
    rms = float(np.max(res.rms_residuals)) if res.rms_residuals is not None and len(res.rms_residuals) else float("inf")
    bc_res = float(np.max(np.abs(bc(res.y[:, 0], res.y[:, -1], res.p))))
    ok = res.status == 0 and np.isfinite(rms) and bc_res <= 10 * tol
    problem = _sanity_problem(case, res.y, res.p) if ok else None
    return res, rms, bc_res, ok and problem is None, problem



def solve_case(
    case: Case,
    *,
    guess: RawSolution | None = None,
    tol: float = 1e-3,
    nodes: int = 200,
    max_nodes: int = 8000,
    start_slip_m_s: float = 1.0,
    slip_factor: float = 0.4,
    max_halvings: int = 6,
    time_limit_s: float = 120.0,
    continuation_tol: float | None = None,
    keep_mesh_below: int = 0,
    mesh_mode: str = "equidistribute",
    step_node_factor: float | None = None,
    min_fraction: float = 2e-3,
    log=None,
) -> RawSolution:
    """Solve one case, by slip-threshold continuation from the geometric guess or by homotopy from ``guess``.

    Every step on the way is solved to ``continuation_tol`` (or ``tol`` if tighter), the last one, at
    ``case`` itself, to ``tol``.  Raises :class:`~dyno.errors.DidNotConverge` naming the case, the
    continuation step and the last residual.
    """
    loose_tol = max(tol, CONTINUATION_TOL if continuation_tol is None else continuation_tol)
    t0 = time.perf_counter()
    # The limit counts this thread's CPU time, not wall time: a loaded machine (or two test workers
    # on two cores) must not turn a solvable case into "did not converge".
    cpu0 = time.thread_time()
    history: list[StepRecord] = []
    last = {"rms": float("nan"), "step": 0, "msg": ""}

    def attempt(c: Case, t, y, p, what: str, final: bool = False):
        ts = time.perf_counter()
        # A step that needs many times its starting mesh is usually a step too far (Newton
        # wandering): cap it so it fails fast and the step is halved.
        factor = STEP_NODE_FACTOR if step_node_factor is None else step_node_factor
        step_nodes = min(max_nodes, max(int(factor * t.size), MIN_STEP_NODES))
        res, rms, bc_res, ok, problem = _solve_once(c, t, y, p, tol if final else loose_tol, step_nodes)
        history.append(StepRecord(len(history) + 1, c.slip_threshold_m_s, res.status, rms, res.x.size,
                                  time.perf_counter() - ts, what))
        last.update(rms=rms, step=len(history), msg=problem or res.message)
        if log is not None:
            log(history[-1])
        return res, rms, bc_res, ok

    def fail(reason: str, at_target_load: bool = True):
        # Gross slip is the answer only if the target asks at least as much as where it stalled: a
        # stall on the way (through a heavier load per tension) says nothing about the target.
        if at_target_load and ("gross slip" in reason or "gross slip" in last["msg"]):
            raise GrossSlip(
                f"gross slip: the belt cannot transmit {case.torque_nm:g} N*m at this tension level for {case.name()} "
                f"(no steady solution: {reason}; last step: {last['msg']})"
            )
        raise DidNotConverge(
            f"belt model did not converge for {case.name()}: {reason} at continuation step {last['step']} "
            f"(last residual {last['rms']:.3g}, tol {tol:g}; {last['msg']})"
        )

    def new_mesh(t, rms, step_tol, fraction=0.25):
        if rms is not None and len(rms) == t.size - 1 and mesh_mode == "equidistribute":
            return equidistributed_mesh(t, rms, step_tol, n_min=min(nodes, 120), n_max=max_nodes // 2,
                                        target_fraction=fraction)
        return remesh(t, nodes)

    def march(start: Case, target: Case, t, y, p, first_fraction: float, what: str, max_fraction: float = 1.0,
              rms=None, final: bool = True):
        """Homotopy from ``start`` (solved: t, y, p) to ``target``; adaptive step.

        ``final``: ``target`` is the case itself, so its last step is solved to ``tol``."""
        s, ds = 0.0, first_fraction
        # a step size that failed is not tried again by growing back to it (the tight end of the slip
        # continuation fails at x0.4 per step every time and passes at x0.5)
        ds_cap = max_fraction
        halvings = 0
        best = None
        c_prev = start
        while s < 1.0:
            if time.thread_time() - cpu0 > time_limit_s:
                fail(f"time limit {time_limit_s:g} s of CPU during {what} at fraction {s:.3g}" + _slip_diagnosis(c_prev, y, p))
            s_new = min(1.0, s + ds)
            c = interp_case(start, target, s_new)
            last_step = final and s_new >= 1.0 and not POLISH
            if t.size > keep_mesh_below:
                mesh = new_mesh(t, rms, tol, FINAL_FRACTION) if last_step else new_mesh(t, rms, loose_tol)
                from scipy.interpolate import PchipInterpolator

                y_guess = PchipInterpolator(t, y, axis=1)(mesh)
            else:
                mesh, y_guess = t, y
            y_guess, p_guess = transfer_guess(c_prev, c, y_guess, p)
            res, rms_max, bc_res, ok = attempt(c, mesh, y_guess, p_guess, f"{what} s={s_new:.3g}", last_step)
            if ok:
                s = s_new
                c_prev = c
                t, y, p, rms = res.x, res.y, res.p, res.rms_residuals
                best = (c, res, rms_max, bc_res)
                halvings = 0
                ds = min(ds * 1.5, ds_cap)
            else:
                halvings += 1
                ds_cap = min(ds_cap, 0.75 * (s_new - s))
                ds = 0.5 * min(ds, 1.0 - s)  # a grown ds may have been clipped at 1: halve the step tried
                if halvings > max_halvings or ds < min_fraction:
                    fail(f"{what} stalled at fraction {s:.3g}" + _slip_diagnosis(c_prev, y, p),
                         _at_least_as_heavy(case, c_prev, _pulleys_at_bound(c_prev, y, p)))
        if final and POLISH and loose_tol > tol:
            best = polish(best)
        return best

    def polish(best):
        """The target, solved to ``continuation_tol``, solved again to ``tol`` on a mesh equidistributed for it.

        Cheaper than solving the last step to ``tol`` at once: the residual the new mesh is built from is the
        target's own, so scipy's refinement needs one or two rounds, not five to seven."""
        c, res = best[0], best[1]
        mesh = new_mesh(res.x, res.rms_residuals, tol, FINAL_FRACTION)
        from scipy.interpolate import PchipInterpolator

        out, rms_max, bc_res, ok = attempt(c, mesh, PchipInterpolator(res.x, res.y, axis=1)(mesh), res.p,
                                           f"to tol {tol:g}", True)
        if not ok:
            fail(f"the solution to {loose_tol:g} did not refine to tol {tol:g}")
        return (c, out, rms_max, bc_res)

    def _from_slack_anchor(c0: Case, r_eq: float, final: bool):
        """Last resort of a cold start at a clamp force: the geometric guess fails at every anchor of that
        force (at a heavy clamp and a light torque the wedge estimate of the tension level is far off:
        1,713 N at 2.6 N*m, ratio 0.72, was a singular Jacobian at all three), but at equal radii and the
        thesis's own tension level (slack span 100 N) it solves; from there the tension condition is switched
        and the radii, torque and force marched to ``c0`` as a warm start does."""
        anchor = replace(c0, r_primary_m=r_eq, r_secondary_m=r_eq, bc="slack_tension", slack_tension_n=100.0)
        t, y, p = initial_guess(anchor, nodes)
        res, rms, bc_res, ok = attempt(anchor, t, y, p, "geometric guess at equal radii, slack span 100 N")
        if not ok:
            fail("first solve from the geometric initial guess failed (also at equal radii, torque x1, x1.8, x0.5, "
                 "and at a slack span of 100 N)")
        start = replace(anchor, bc=c0.bc, axial_force_n=float(res.y[P_A, -1] * AXIAL_REF_N))
        best = march(start, c0, res.x, res.y, res.p, 1.0, "force continuation from a slack-span anchor",
                     rms=res.rms_residuals, final=final)
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
        t, y, p, rms0 = guess.t, guess.y, guess.p, guess.rms_residuals
        if target.bc == "slack_tension" and target.slack_tension_n < start.slack_tension_n:
            # Lower the tension last (raise it first, below): the straight path to a lighter belt
            # can pass through a heavier load per tension than either end (gross slip on the way).
            mid = replace(target, slack_tension_n=start.slack_tension_n)
            c_mid, res_mid, _, _ = march(start, mid, t, y, p, 1.0, "warm-start homotopy (tension last)", rms=rms0,
                                         final=False)
            start, t, y, p, rms0 = c_mid, res_mid.x, res_mid.y, res_mid.p, res_mid.rms_residuals
        best = march(start, target, t, y, p, 1.0, "warm-start homotopy", rms=rms0)
    else:
        t, y, p = initial_guess(case, nodes)
        # From the guess, solve with a heavily smoothed friction law first.
        v_start = max(start_slip_m_s, case.slip_threshold_m_s)
        c0 = replace(case, slip_threshold_m_s=v_start)
        c0_final = v_start <= case.slip_threshold_m_s  # no slip-threshold continuation after c0
        res, rms, bc_res, ok = attempt(c0, t, y, p, "geometric guess", c0_final)
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
                anchor = None
            if anchor is not None:
                best = march(anchor, c0, res.x, res.y, res.p, 0.25, "ratio continuation", rms=res.rms_residuals,
                             final=c0_final)
            elif case.bc != "slack_tension":
                best = _from_slack_anchor(c0, r_eq, c0_final)
            else:
                fail("first solve from the geometric initial guess failed (also at equal radii, torque x1, x1.8, x0.5)")
            res = best[1]
        if v_start > case.slip_threshold_m_s:
            n_steps = math.log(v_start / case.slip_threshold_m_s) / -math.log(slip_factor)
            frac = 1.0 / max(n_steps, 1.0)
            best = march(c0, case, res.x, res.y, res.p, frac, "slip-threshold continuation",
                         max_fraction=SLIP_STEP_GROWTH * frac,
                         rms=res.rms_residuals)
    c, res, rms, bc_res = best
    return RawSolution(
        case=case, t=res.x, y=res.y, p=res.p, sol=res.sol, residual_max=rms, bc_residual_max=bc_res, tol=tol,
        history=history, solve_s=time.perf_counter() - t0, rms_residuals=res.rms_residuals,
    )
