"""One belt-model prediction, as stored: the solving strategy (warm, cold, a far neighbour) and the result's
shape — the part of the overlay that decides the numbers.

The cache's key hashes this module with the maths (:data:`dyno.model.cache_keys.MODEL_MODULES`); the
service, the worker processes and the executors that carry a job (:mod:`dyno.model.overlay_service`,
:mod:`dyno.model.overlay_worker`) do not, so a change to the plumbing keeps every cached result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dyno.model.params import ModelParams, OperatingPoint


@dataclass
class WarmState:
    """What a warm start needs of a solution (small, picklable): quacks like a BeltSolution for ``guess=``."""

    case: object  # dyno.model.equations.Case
    t: np.ndarray
    y: np.ndarray
    p: np.ndarray
    rms: np.ndarray | None
    op: OperatingPoint
    variant: str
    slip_threshold_m_s: float

    @property
    def raw(self):
        from dyno.model.equations import RawSolution

        return RawSolution(case=self.case, t=self.t, y=self.y, p=self.p, sol=None, residual_max=0.0,
                           bc_residual_max=0.0, tol=0.0, rms_residuals=self.rms)


def closed_form_result(params, op) -> dict:
    from dyno.model.closed_form import closed_form_point

    r = closed_form_point(params, op)
    return {
        "converged": True,
        "tier": "closed_form",
        "efficiency": {"speed": r.efficiency_speed, "torque": r.efficiency_torque, "overall": r.efficiency_overall},
        "axial_force_n": {"primary": r.axial_force_primary_n, "secondary": r.axial_force_secondary_n},
        "span_tension_n": {"tight": r.tight_tension_n, "slack": r.slack_tension_n},
    }


def summary_result(sol) -> dict:
    s = sol.summary
    res = {"converged": True, "tier": "full", "efficiency": s["efficiency"], "axial_force_n": s["axial_force_n"],
           "span_tension_n": s["span_tension_n"], "residual_max": s["residual_max"],
           "slip_threshold_m_s": s["slip_threshold_m_s"], "solve_s": s["solve_s"], "balance": s["balance"]}
    if "warning" in s:
        res["warning"] = s["warning"]
    return res


def solve_steps(sol) -> int:
    raw = getattr(sol, "raw", None)
    return len(getattr(raw, "history", []) or [])


def solve_strategy(params: ModelParams, op: OperatingPoint, *, guess: WarmState | None = None,
                   fallback: WarmState | None = None, **kwargs) -> tuple[dict, WarmState | None, str, int]:
    """Solve one point (warm from ``guess`` if given, cold if that fails): (result, WarmState or None, start, steps).

    ``fallback``: a solution too far for a first try (a cold start is usually quicker), started from when the
    cold start fails without a physical verdict.  The cold path's first steps use a smoothed friction law
    (v_th = 1 m/s) at which a heavy load reaches the capstan bound on the way: e.g. 17.5 N*m at 856 N,
    ratio 0.72, stalled cold and converged warm from Table 6.1's point in 3 steps.  ``kwargs``:
    :func:`dyno.model.solution.solve_point`'s (variant, slip threshold, tol, time limit, log).
    """
    from dyno.errors import MODEL_FAILURES
    from dyno.model import solution

    sol, start, steps, exc = None, "cold", 0, None
    if guess is not None:
        try:
            sol, start = solution.solve_point(params, op, guess=guess, **kwargs), "warm"
        except MODEL_FAILURES as e:  # a worse start than none: solve cold below
            exc, start = e, "cold after a failed warm start"
    if sol is None:
        try:
            sol = solution.solve_point(params, op, **kwargs)
        except MODEL_FAILURES as e:
            exc = e
    if sol is None and fallback is not None and type(exc).__name__ != "GrossSlip":
        try:
            sol = solution.solve_point(params, op, guess=fallback, **kwargs)
            start = "warm from a far neighbour after a failed cold start"
        except MODEL_FAILURES as e:
            exc = e
    if sol is None:
        res = {"converged": False, "tier": "full", "error": str(exc),
               "state": "gross_slip" if type(exc).__name__ == "GrossSlip" else "failed"}
        return res, None, start, steps
    raw = sol.raw
    warm = WarmState(case=raw.case, t=raw.t, y=raw.y, p=raw.p, rms=raw.rms_residuals, op=op,
                     variant=kwargs.get("variant", "corrected"), slip_threshold_m_s=kwargs["slip_threshold_m_s"])
    return summary_result(sol), warm, start, solve_steps(sol)
