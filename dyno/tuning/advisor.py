"""The tune advisor: from measured runs to the parts to fit (``dyno tune advise``).

1. calibrate the parts' effective values from the runs (:mod:`dyno.tuning.advisor_model`);
2. enumerate every tune that changes at most ``max_changes`` parts of the latest run's tune, with
   catalogue parts that fit its clutch family and are not marked incompatible with each other
   (exhaustive: the shipped catalogue gives ~1,600 tunes at 2 changes);
3. predict each tune's targeted figures (a first pass at the calibrated values for every tune, then
   value and uncertainty for the :data:`REFINE` best);
4. rank by the probability that every target is met within ``tolerance_rpm`` (the prediction taken as
   normal with its u), then fewer changes, then the smaller normalised miss.

Beyond a catalogue of a few thousand combinations the first pass is what grows; a documented
optimiser (coordinate descent over parts from the best first-pass tunes) is the way to go then --
not needed for the shipped catalogue, so not built.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

from dyno.tuning.advisor_model import (UNKNOWN_PART_TOLERANCE_REL, Calibration, RunData, calibrate,
                                       calibrated_theta, calibrated_thrust, effective_tune, predict_figure,
                                       predict_with_u, tune_params)
from dyno.tuning.advisor_plan import engagement_limit_rpm, two_trip_probability
from dyno.tuning.parts import DEVIATED, Part, apply_part, match_parts, part_identity

REFINE = 120            # tunes whose uncertainty is computed after the first pass (half with a full-load target)
FULL_LOAD_PASS = 300    # with a full-load target: tunes (best by the light figures) whose full load is solved
TARGET_FIGURES = ("engagement", "shift_out", "full_load")


@dataclass
class Candidate:
    tune: object
    changes: list[Part]
    first_pass: dict = field(default_factory=dict)
    predicted: dict = field(default_factory=dict)   # figure -> (rpm, u_rpm)
    p_hit: float = 0.0
    p_two: float = 0.0     # P(met now or after one adjustment of the same parts): dyno.tuning.advisor_plan
    miss: float = math.inf
    adjusted_miss: float = math.inf


def _phi(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


def p_within(mean: float, u: float, target: float, tol: float) -> float:
    if not (math.isfinite(mean) and math.isfinite(u)) or u <= 0:
        return 0.0
    return _phi((target + tol - mean) / u) - _phi((target - tol - mean) / u)


class Tolerances:
    """``tolerance_of(identity, kind)``: a catalogue part's stated tolerance, else the default (picklable:
    it travels with the refine tasks to pool or Dask workers)."""

    def __init__(self, table: dict[str, float]) -> None:
        self.table = table

    def __call__(self, ident: str, kind: str) -> float:
        return self.table.get(ident, UNKNOWN_PART_TOLERANCE_REL)


def tolerance_lookup(catalogue: list[Part], tunes) -> Tolerances:
    table: dict[str, float] = {}
    for t in tunes:
        for p in catalogue:
            table.setdefault(part_identity(apply_part(t, p), p.kind), p.tolerance_rel)
    return Tolerances(table)


def _refine_task(args):
    """One tune's predicted figures with u (module level: an executor's task)."""
    cal, tune, figures, load, low, tol_of, engine = args
    return {f: predict_with_u(cal, tune, f, load, low, tol_of, engine) for f in figures}


def candidates(base, catalogue: list[Part], max_changes: int) -> tuple[list[Candidate], dict]:
    """Every tune with at most ``max_changes`` parts of ``base`` replaced by catalogue parts that fit."""
    current = match_parts(base, catalogue)
    families = {p.fits for p in current.values() if p is not None}
    usable = [p for p in catalogue if (not families or p.fits in families) and p.kind in DEVIATED
              and getattr(base, p.kind, None) is not None]
    by_kind: dict[str, list[Part]] = {}
    for p in usable:
        if part_identity(apply_part(base, p), p.kind, with_settings=True) != part_identity(base, p.kind,
                                                                                         with_settings=True):
            by_kind.setdefault(p.kind, []).append(p)
    out = [Candidate(base, [])]
    kinds = sorted(by_kind)
    for n in range(1, max_changes + 1):
        for combo in itertools.combinations(kinds, n):
            for parts in itertools.product(*(by_kind[k] for k in combo)):
                fitted = set(parts) | {p for k, p in current.items() if p is not None and k not in combo}
                ids = {p.id.split("@")[0] for p in fitted}
                if any(i in ids for p in fitted for i in p.incompatible_with):
                    continue
                t = base
                for p in parts:
                    t = apply_part(t, p)
                out.append(Candidate(t, list(parts)))
    info = {"families": sorted(families), "current": {k: (p.id if p else None) for k, p in current.items()},
            "choices_per_kind": {k: len(v) for k, v in by_kind.items()}}
    return out, info


def advise(runs: list[RunData], catalogue: list[Part], targets: dict[str, float], *, max_changes: int = 2,
           tolerance_rpm: float = 50.0, top: int = 5, executor=None) -> dict:
    """Calibrate, search, rank. ``targets``: figure -> rpm (``engagement``, ``shift_out``, ``full_load``).
    ``executor`` (:func:`dyno.model.executor.make_executor`: a local pool or Dask) runs the refine step's
    tunes; None: in this process."""
    base_run = runs[-1]
    base = base_run.tune
    tol_of = tolerance_lookup(catalogue, [r.tune for r in runs])
    cal = calibrate(runs, tol_of)
    idx = cal.index()
    # the light load and the low-gear ratio the figures are predicted at: the latest engagement run's
    # (a steady run has neither; the tune's geometric low stop then)
    eng_runs = [r for r in runs if r.figures and math.isfinite(r.low_ratio)]
    load = eng_runs[-1].light_load_nm if eng_runs else 0.2
    if eng_runs:
        low = eng_runs[-1].low_ratio
    else:
        from dyno.tuning.shift_curve import Solver
        from dyno.tuning.tune import model_params_for

        low = Solver(base, None, model_params_for(base)).ratio_low_stop
    engine = base_run.engine or next((r.engine for r in reversed(runs) if r.engine is not None), None)
    if "full_load" in targets and engine is None:
        from dyno.errors import ConfigError

        raise ConfigError(base_run.path, "engine_map.csv", "the run's engine map (a full_load target needs it)")
    cands, info = candidates(base, catalogue, max_changes)
    theta, thrust = calibrated_theta(cal), calibrated_thrust(cal)
    # first pass: the calibrated values only (cheap)
    light = [f for f in targets if f != "full_load"]
    for c in cands:
        ps = tune_params(c.tune, tol_of)
        d = [cal.d[idx[(p.part, p.field)]] if (p.part, p.field) in idx else 0.0 for p in ps]
        eff = effective_tune(c.tune, ps, d)
        c.first_pass = {f: predict_figure(eff, f, load, low, engine, theta, thrust) for f in light}
        c.miss = sum(((c.first_pass[f] - targets[f]) / tolerance_rpm) ** 2 for f in light)
        c.miss = c.miss if math.isfinite(c.miss) else math.inf
    cands.sort(key=lambda c: (c.miss, len(c.changes)))
    n_refine = REFINE
    if "full_load" in targets:  # a root solve per tune: for the light figures' best FULL_LOAD_PASS only
        n_refine = REFINE // 2
        for c in cands[:FULL_LOAD_PASS]:
            ps = tune_params(c.tune, tol_of)
            d = [cal.d[idx[(p.part, p.field)]] if (p.part, p.field) in idx else 0.0 for p in ps]
            c.first_pass["full_load"] = predict_figure(effective_tune(c.tune, ps, d), "full_load", load, low,
                                                       engine, theta)
            c.miss += ((c.first_pass["full_load"] - targets["full_load"]) / tolerance_rpm) ** 2
        for c in cands[FULL_LOAD_PASS:]:
            c.miss = math.inf
        cands.sort(key=lambda c: (c.miss, len(c.changes)))
    lookahead = "full_load" not in targets
    refined = cands[:n_refine]
    if lookahead:  # and the tunes that washers would bring to the targets (aimed high, trimmed next trip)
        _adjusted_miss(cands, catalogue, base, targets, tolerance_rpm)
        chosen = {id(c) for c in refined}
        refined += [c for c in sorted(cands, key=lambda c: c.adjusted_miss)[:n_refine // 2] if id(c) not in chosen]
    refined += [c for c in cands if not c.changes and all(c is not r for r in refined)]  # the current tune always
    from dyno.model.executor import InlineExecutor

    tasks = [(cal, c.tune, tuple(targets), load, low, tol_of, engine) for c in refined]
    for i, pred in (executor or InlineExecutor()).map_unordered(_refine_task, tasks):
        refined[i].predicted = pred
    limit = engagement_limit_rpm()
    for c in refined:
        c.p_hit = math.prod(p_within(*c.predicted[f], targets[f], tolerance_rpm) for f in targets)
        if "engagement" in c.predicted:  # a tune that may engage too high for the rig's check may abort
            m, u = c.predicted["engagement"]
            c.p_hit *= _phi((limit - m) / u) if math.isfinite(m) and u > 0 else 0.0
        c.miss = sum(((c.predicted[f][0] - targets[f]) / tolerance_rpm) ** 2 for f in targets)
        c.p_two = c.p_hit
        if lookahead and c.changes:
            c.p_two = max(c.p_hit, two_trip_probability(cal, c.tune, catalogue, targets, tolerance_rpm, load, low,
                                                        tol_of))
    # ranked by the chance of meeting the targets within two trips (this one, then an adjustment of the
    # parts it brings), then by this trip's
    refined.sort(key=lambda c: (-round(c.p_two, 2), -round(c.p_hit, 3), len(c.changes), c.miss))
    current = next(c for c in refined if not c.changes)
    # the tune the runs measured is not advice: another trip on it would measure what they measured
    # (it is reported as "current", with its own P)
    refined = [c for c in refined if c.changes]
    return {"targets": {f"{f}_rpm": v for f, v in targets.items()}, "tolerance_rpm": tolerance_rpm,
            "max_changes": max_changes, "runs": [str(r.path) for r in runs], "base_tune": base.name,
            "load_nm": load, "low_ratio": low, "searched": len(cands), "refined": len(refined),
            "catalogue": info, "calibration": cal.to_dict(),
            "current": _row(current, targets), "ranked": [_row(c, targets) for c in refined[:top]],
            "_candidates": refined[:top], "_calibration": cal}


def _row(c: Candidate, targets) -> dict:
    return {"changes": [{"kind": p.kind, "part": p.id, "label": p.label, "source": p.source} for p in c.changes],
            "predicted": {f: {"rpm": c.predicted[f][0], "u_rpm": c.predicted[f][1],
                              "u95_rpm": 2.0 * c.predicted[f][1]} for f in c.predicted},
            "p_within_tolerance": c.p_hit, "p_within_two_trips": c.p_two}


def curve_for(cal: Calibration, tune, engine, tol_of, n_points: int = 30):
    """The predicted shift curve of a tune at its calibrated part values (for the page)."""
    from dyno.tuning.fit import NOMINAL, solver_for
    from dyno.tuning.shift_curve import predict_shift_curve

    ps = tune_params(tune, tol_of)
    idx = cal.index()
    d = [cal.d[idx[(p.part, p.field)]] if (p.part, p.field) in idx else 0.0 for p in ps]
    eff = effective_tune(tune, ps, d)
    sv = solver_for(eff, engine, calibrated_theta(cal) or NOMINAL)
    return predict_shift_curve(eff, engine, n_points=n_points, params=sv.params,
                               secondary_friction_torque_nm=sv.secondary_friction_torque_nm,
                               flyweight_radius_offset_m=sv.flyweight_radius_offset_m)


def _adjusted_miss(cands: list[Candidate], catalogue: list[Part], base, targets: dict, tol: float) -> None:
    """Each first-pass tune's normalised miss after the best washer change on its flyweight bodies (the
    clamp goes as m n^2, so the figures scale as (m / m')^(1/2)): to bring into the refine step the tunes
    a second trip could trim onto the targets."""
    light = [f for f in targets if f != "full_load"]
    options: dict[str, list[float]] = {}
    for p in catalogue:
        if p.kind == "flyweights" and getattr(base, "flyweights", None) is not None:
            t = apply_part(base, p)
            options.setdefault(part_identity(t, "flyweights"), []).append(t.flyweights.mass_each_kg)
    for c in cands:
        c.adjusted_miss = c.miss
        fw = getattr(c.tune, "flyweights", None)
        if fw is None or not math.isfinite(c.miss):
            continue
        for m in options.get(part_identity(c.tune, "flyweights"), ()):
            k = math.sqrt(fw.mass_each_kg / m)
            miss = sum(((c.first_pass[f] * k - targets[f]) / tol) ** 2 for f in light)
            c.adjusted_miss = min(c.adjusted_miss, miss)
