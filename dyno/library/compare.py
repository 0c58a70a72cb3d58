"""Compare runs: curves on a common secondary-rpm grid, differences with their uncertainty, tune diff.

Pure (no I/O): the inputs are what :func:`dyno.library.summary.read_run_files` reads.

Each run's steady points are a sampled curve ``y(n_s)`` with a standard error per
point.  To compare two runs whose points fall at different secondary speeds, both
are interpolated linearly onto a common grid inside the speed range they share.
The interpolated value's uncertainty has two parts, added in quadrature:

* the points' own standard errors carried through the interpolation weights,
  ``s^2 = (1-w)^2 s_i^2 + w^2 s_{i+1}^2``;
* the interpolation error of a curved curve: the linear interpolant misses
  ``f'' (x - x_i)(x_{i+1} - x) / 2`` (the remainder of linear interpolation), with
  ``f''`` estimated from the neighbouring points' second divided differences.

The difference ``d = y_B - y_A`` has ``s_d = sqrt(s_A^2 + s_B^2)`` (independent runs) and
is called significant at 95 % when ``|d| > 1.96 s_d``.  Neighbouring grid points share
points, so their verdicts are correlated: read a run of significant grid points as one
finding.

The efficiency difference also has a stated 95 % uncertainty ``difference_u95`` that adds the
systematic terms (calibration, engine map, air) to the statistical part — only what does not cancel
between the two runs (:mod:`dyno.library.compare_terms`); each term is reported "residual", "not
cancelled" (or "unknown") with its reason.  The air each run was corrected to (``meta.ambient``) is
stated in ``atmosphere``.
"""

from __future__ import annotations

import math

import numpy as np

Z95 = 1.959964  # two-sided 95 % normal quantile

#: compared quantity -> (point key, standard-error key or None, unit, label, sim truth key)
QUANTITIES = {
    "efficiency": ("efficiency", "efficiency_sem", "", "efficiency", "efficiency_true"),
    "torque_secondary_nm": ("torque_secondary_nm", "torque_secondary_sem_nm", "N·m", "secondary torque",
                            "torque_secondary_true_nm"),
    "power_out_w": ("power_out_w", None, "W", "output power", "power_out_true_w"),
    "rpm_primary": ("rpm_primary", "rpm_primary_sem", "rpm", "primary speed (shift curve)", "rpm_primary_true"),
}
def _setup_value(row: dict, k: str):
    """What a person can read: a plan by its mode (step / speed-hold) beside its hash."""
    v = row.get(k)
    if k == "plan_sha256" and v and row.get("plan_json"):
        import json

        try:
            mode = json.loads(row["plan_json"]).get("mode", "step")
        except (ValueError, AttributeError):
            return v
        return f"{mode} ({v[:8]})"
    return v


SETUP_FIELDS = ("mode", "seed", "tune_name", "tune_sha256", "calibration_date", "calibration_slope_counts_per_nm",
                "engine_map_sha256", "plan_sha256", "settle_mode", "protocol", "firmware_version",
                "software_version", "atm_pressure_kpa", "atm_temperature_c", "atm_humidity_pct")
#: runs from before the air was logged (no ``meta.ambient``): what their input power is
ATMOSPHERE_NOTE = ("atmospheric correction: not applied (the runs record no ambient pressure, temperature or "
                   "humidity; input power is each run's engine map as recorded)")


def atmosphere_note(runs: list[dict]) -> str:
    """What air each run's input power was taken to (its ``meta.ambient``), one clause per run."""
    from dyno.library.compare_terms import describe_air, run_systematics

    sys_ = [run_systematics(r) for r in runs]
    if not any(s["has_ambient"] for s in sys_):
        return ATMOSPHERE_NOTE
    return "air: " + "; ".join(f"{r['name']}: {describe_air(s['ambient'], s['has_ambient'])}"
                               for r, s in zip(runs, sys_))


def _f(x):
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else math.nan


def power_sem(p: dict) -> float:
    """Standard error of P = T * 2 pi n / 60 from the torque's and the speed's (independent)."""
    t, st = _f(p.get("torque_secondary_nm")), _f(p.get("torque_secondary_sem_nm"))
    n, sn = _f(p.get("rpm_secondary")), _f(p.get("rpm_secondary_sem"))
    pw = _f(p.get("power_out_w"))
    if not (t and n) or math.isnan(pw):
        return math.nan
    rel = math.hypot(st / t if not math.isnan(st) else 0.0, sn / n if not math.isnan(sn) else 0.0)
    return abs(pw) * rel


def series(points: list[dict]) -> dict:
    """The valid points as sorted arrays: ``rpm_secondary`` and, per quantity, value/sem/truth."""
    good = [p for p in points if p.get("valid") and not math.isnan(_f(p.get("rpm_secondary")))
            and not math.isnan(_f(p.get("efficiency")))]
    good.sort(key=lambda p: _f(p["rpm_secondary"]))
    out = {"rpm_secondary": np.array([_f(p["rpm_secondary"]) for p in good])}
    for q, (k, sk, *_rest, tk) in QUANTITIES.items():
        out[q] = np.array([_f(p.get(k)) for p in good])
        sems = [power_sem(p) if sk is None else _f(p.get(sk)) for p in good]
        out[q + "_sem"] = np.array([0.0 if math.isnan(s) else s for s in sems])
        out[q + "_true"] = np.array([_f(p.get(tk)) for p in good])
    return out


def interpolate(x: np.ndarray, y: np.ndarray, sem: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of ``y(x) ± sem`` onto ``grid`` with the uncertainty described above.

    Grid values outside ``[x[0], x[-1]]`` are NaN.  ``x`` sorted; repeated speeds are averaged.
    """
    x, inv = np.unique(x, return_inverse=True)
    if len(x) < 2:
        return np.full(grid.shape, np.nan), np.full(grid.shape, np.nan)
    cnt = np.bincount(inv)
    y = np.bincount(inv, weights=y) / cnt
    sem = np.sqrt(np.bincount(inv, weights=sem ** 2)) / cnt
    # second divided differences at interior points, then per interval the larger neighbour
    curv = np.zeros(len(x))
    if len(x) >= 3:
        d1 = np.diff(y) / np.diff(x)
        curv[1:-1] = np.abs(2.0 * np.diff(d1) / (x[2:] - x[:-2]))
        curv[0], curv[-1] = curv[1], curv[-2]
    val = np.full(grid.shape, np.nan)
    err = np.full(grid.shape, np.nan)
    inside = (grid >= x[0]) & (grid <= x[-1])
    g = grid[inside]
    i = np.clip(np.searchsorted(x, g, side="right") - 1, 0, len(x) - 2)
    h = x[i + 1] - x[i]
    w = (g - x[i]) / h
    val[inside] = (1 - w) * y[i] + w * y[i + 1]
    stat = np.sqrt(((1 - w) * sem[i]) ** 2 + (w * sem[i + 1]) ** 2)
    fpp = np.maximum(curv[i], curv[i + 1])
    interp_err = fpp * (g - x[i]) * (x[i + 1] - g) / 2.0
    err[inside] = np.hypot(stat, interp_err)
    return val, err


def common_grid(all_series: list[dict], step_rpm: float) -> np.ndarray:
    lo = max(s["rpm_secondary"][0] for s in all_series)
    hi = min(s["rpm_secondary"][-1] for s in all_series)
    if not hi > lo:
        return np.array([])
    start = math.ceil(lo / step_rpm) * step_rpm
    return np.arange(start, hi + 1e-9, step_rpm)


def flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, name + "."))
        else:
            out[name] = v
    return out


def dict_diff(a: dict, b: dict) -> list[dict]:
    """Which dotted keys differ between two nested mappings: ``{"key", "from", "to"}`` (None = absent)."""
    fa, fb = flatten(a or {}), flatten(b or {})
    return [{"key": k, "from": fa.get(k), "to": fb.get(k)} for k in sorted(set(fa) | set(fb)) if fa.get(k) != fb.get(k)]


def _tare_on_grid(run: dict, calibration_rel: float, grid: np.ndarray) -> np.ndarray:
    """Each valid point's tare part of its calibration term (relative), interpolated onto the grid."""
    from dyno.library.compare_terms import point_tare_rel

    good = sorted((p for p in run["points"] if p.get("valid") and not math.isnan(_f(p.get("rpm_secondary")))
                   and not math.isnan(_f(p.get("efficiency")))), key=lambda p: _f(p["rpm_secondary"]))
    x = np.array([_f(p["rpm_secondary"]) for p in good])
    t = np.array([point_tare_rel(p, calibration_rel) for p in good])
    return interpolate(x, t, np.zeros(len(x)), grid)[0]


def _efficiency_u95(sys_, tare, curves, i: int, sem_d, grid) -> tuple[dict, dict]:
    """Run ``i`` against run 0: the efficiency difference's ``U_d`` with its terms (compare_terms)."""
    from dyno.library.compare_terms import difference_terms

    ref, cur = curves[0], curves[i]
    res = difference_terms(ref["efficiency"]["value"], cur["efficiency"]["value"], ref["rpm_primary"]["value"],
                           cur["rpm_primary"]["value"], sem_d, tare[0], tare[i], sys_[0], sys_[i])
    per_point = {k: np.broadcast_to(t["u95"], grid.shape) for k, t in res["terms"].items()}
    summary = {k: {"status": t["status"], "reason": t["reason"],
                   "max_u95": float(np.nanmax(per_point[k])) if np.isfinite(per_point[k]).any() else None}
               for k, t in res["terms"].items()}
    return {"difference_u95": res["u95"], "difference_u95_terms": per_point}, summary


def _torque_u95(sys_, tare, curves, i: int, q: str, sem_d) -> dict:
    """Torque and output power: the statistics and the calibration (its slope's residual and each run's tare,
    which a statistical s.e. does not see: every run reads its own zero before GO); no map, no air."""
    from dyno.library.compare_terms import calibration_term

    cal = calibration_term(curves[0][q]["value"], curves[i][q]["value"], tare[0], tare[i], sys_[0], sys_[i])
    u95 = np.hypot(Z95 * np.asarray(sem_d, float), np.nan_to_num(cal["u95"]))
    return {"difference_u95": u95, "difference_u95_terms": {"statistical": Z95 * np.asarray(sem_d, float),
                                                              "calibration": np.broadcast_to(cal["u95"], u95.shape)}}


def compare(runs: list[dict], step_rpm: float = 200.0) -> dict:
    """Compare ``runs`` (each ``{"name", "row", "points", "tune", "meta"?}``) against the first.

    Returns the grid, each run's curve on it, per other run the differences with
    their uncertainty and 95 % verdicts, the tune diff and the setup diff; every
    number as a plain list (JSON-ready, NaN as None).
    """
    ser = [series(r["points"]) for r in runs]
    for r, s in zip(runs, ser):
        if len(s["rpm_secondary"]) < 2:
            raise ValueError(f"{r['name']}: fewer than two valid points to draw a curve from")
    grid = common_grid(ser, step_rpm)
    if grid.size == 0:
        raise ValueError("the runs share no secondary-rpm range")
    curves = []
    for r, s in zip(runs, ser):
        c = {"name": r["name"], "points": {q: {"rpm_secondary": s["rpm_secondary"], "value": s[q], "sem": s[q + "_sem"]}
                                            for q in QUANTITIES}}
        for q in QUANTITIES:
            v, e = interpolate(s["rpm_secondary"], s[q], s[q + "_sem"], grid)
            c[q] = {"value": v, "sem": e}
            t = s[q + "_true"]
            if np.isfinite(t).sum() >= 2:
                ok = np.isfinite(t)
                c[q]["truth"] = interpolate(s["rpm_secondary"][ok], t[ok], np.zeros(ok.sum()), grid)[0]
        curves.append(c)
    ref = curves[0]
    from dyno.library.compare_terms import run_systematics

    sys_ = [run_systematics(r) for r in runs]  # what each run says of its systematic terms (meta.json)
    tare = [_tare_on_grid(r, s["calibration_rel"], grid) for r, s in zip(runs, sys_)]
    diffs = []
    for i, (r, c) in enumerate(zip(runs[1:], curves[1:]), start=1):
        entry = {"name": c["name"], "reference": ref["name"], "quantities": {}}
        for q in QUANTITIES:
            d = c[q]["value"] - ref[q]["value"]
            sd = np.hypot(c[q]["sem"], ref[q]["sem"])
            with np.errstate(invalid="ignore", divide="ignore"):
                z = d / sd
            qd = {"difference": d, "sem": sd, "z": z, "significant": np.abs(z) > Z95}
            if "truth" in c[q] and "truth" in ref[q]:
                qd["truth_difference"] = c[q]["truth"] - ref[q]["truth"]
            if q == "efficiency":  # its stated uncertainty: what does not cancel between the two runs
                extra, entry["terms"] = _efficiency_u95(sys_, tare, curves, i, sd, grid)
            elif q in ("torque_secondary_nm", "power_out_w"):
                extra = _torque_u95(sys_, tare, curves, i, q, sd)
            else:
                extra = None
            if extra is not None:
                qd.update(extra)
                with np.errstate(invalid="ignore"):
                    qd["significant_u95"] = np.abs(d) > extra["difference_u95"]
            entry["quantities"][q] = qd
        entry["tune_diff"] = dict_diff((runs[0].get("tune") or {}), (r.get("tune") or {}))
        entry["setup_diff"] = [{"key": k, "from": _setup_value(runs[0]["row"], k), "to": _setup_value(r["row"], k)}
                               for k in SETUP_FIELDS if runs[0]["row"].get(k) != r["row"].get(k)]
        diffs.append(entry)
    return _plain({"grid_rpm_secondary": grid, "step_rpm": step_rpm, "confidence": 0.95, "curves": curves,
                   "differences": diffs, "atmosphere": atmosphere_note(runs),
                   "runs": [{"name": r["name"], **{k: r["row"].get(k) for k in ("path", "state", "n_points")},
                             "ambient": (r.get("meta") or {}).get("ambient")} for r in runs]})


def _plain(obj):
    if isinstance(obj, np.ndarray):
        return [_plain(x) for x in obj.tolist()]
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj
