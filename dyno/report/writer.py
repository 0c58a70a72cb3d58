"""Reads a run directory into :class:`ReportData` and writes ``report.html`` next to it (atomically).

The optional parts (belt-model overlay, predicted shift curve, engine-map figure) are best effort: one
that cannot be made leaves a note in the report instead of failing it.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

from dyno.report.html import ReportData, exclusion_reason, render_report

REPORT_NAME = "report.html"
RAD_S_PER_RPM = 2.0 * math.pi / 60.0
#: optional parts may fail for many reasons (a tune the solver cannot place, a map without power...)
_OPTIONAL_ERRORS = (ArithmeticError, ValueError, KeyError, TypeError, OSError, RuntimeError)


def _engine_map(path: Path, notes: list) -> dict | None:
    from dyno.analysis.engine_map import load_engine_map

    try:
        m = load_engine_map(path)
    except _OPTIONAL_ERRORS as exc:
        notes.append(f"engine map not shown: {exc}")
        return None
    import numpy as np

    rpm = np.linspace(m.rpm_min, m.rpm_max, 60)  # exact end points: the map refuses to extrapolate
    comments = [ln.lstrip("#").strip() for ln in path.read_text(encoding="utf-8").splitlines()
                if ln.startswith("#") and ln.lstrip("#").strip()]
    return {"rpm": rpm.tolist(), "torque_nm": np.asarray(m.torque_nm(rpm), float).tolist(),
            "power_w": np.asarray(m.power_w(rpm), float).tolist(), "source": m.source, "sha256": m.sha256,
            "j1349_factor": m.j1349_factor, "notes": comments}


BOUND_LABEL = "closed form, Table 6.1 belt: creep loss only, an upper bound"
FULL_LABEL = "full model (thesis BVP), Table 6.1 belt"


def _model(points: list, notes: list, full: bool = False, tune_path: Path | None = None) -> dict | None:
    """The belt model at each plotted point: the full model (thesis BVP, with its losses) when asked, else
    wherever the model cache already holds it (the UI's overlay solved it during the run); the closed form
    (instant, creep loss only: an upper bound) only for the points left, as its own labelled series.  Each
    point's input is the slip-consistent inverse's (geometric ratio and the run's tune's clamp,
    ``overlay_inputs``)."""
    from dyno.model.overlay_inputs import overlay_inputs

    kept = [p for p in points if not exclusion_reason(p) and (p.get("power_in_w") or 0) > 0]
    tune = tune_path if tune_path is not None and tune_path.is_file() else None
    try:
        pairs = overlay_inputs(kept, tune)
    except _OPTIONAL_ERRORS as exc:
        notes.append(f"belt-model overlay not shown: {exc}")
        return None
    if len(pairs) < len(kept):
        notes.append(f"belt model: {len(kept) - len(pairs)} of {len(kept)} points have no steady belt at the "
                     "tune's clamp (inverse: gross slip or no clamp)")
    if not pairs:
        return None
    from dyno.model.overlay import cached_mask, predict_overlay

    is_full = [True] * len(pairs) if full else cached_mask([op for _, op in pairs])
    series = {}
    for tier, want in (("full", True), ("closed_form", False)):
        sel = [xo for xo, f in zip(pairs, is_full) if f == want]
        if not sel:
            continue
        try:
            pred = predict_overlay([op for _, op in sel], tier=tier, time_limit_s=20.0)
        except _OPTIONAL_ERRORS as exc:
            notes.append(f"belt-model overlay ({tier}) not shown: {exc}")
            continue
        got = sorted((x, float(r["efficiency"]["overall"])) for (x, _), r in zip(sel, pred) if r.get("converged"))
        if len(got) < len(sel):
            notes.append(f"belt model ({tier}): {len(sel) - len(got)} of {len(sel)} points did not converge")
        if got:
            series[tier] = {"rpm_secondary": [x for x, _ in got], "efficiency": [e for _, e in got]}
    if not series:
        return None
    main = series.get("full") or {"rpm_secondary": [], "efficiency": []}
    n_full, n = len(main["rpm_secondary"]), len(pairs)
    if "closed_form" not in series:
        label = f"{FULL_LABEL} at all {n_full} points"
    elif n_full:
        label = (f"{FULL_LABEL} at {n_full} of {n} points (the model cache's); the other "
                 f"{n - n_full}: {BOUND_LABEL}; `dyno report RUN --model full` solves them")
    else:
        label = f"{BOUND_LABEL} (the full model is not solved for this run: `dyno report RUN --model full`)"
    tier = "full" if "closed_form" not in series else ("mixed" if n_full else "closed_form")
    return {"rpm_secondary": main["rpm_secondary"], "efficiency": main["efficiency"], "label": label,
            "tier": tier, "n_full": n_full, "n_points": n,
            "bound": ({**series["closed_form"], "label": BOUND_LABEL} if "closed_form" in series else None)}


def _predicted_shift(run_dir: Path, notes: list) -> dict | None:
    tune_path, map_path = run_dir / "tune.toml", run_dir / "engine_map.csv"
    if not (tune_path.exists() and map_path.exists()):
        return None
    from dyno.errors import DynoError
    from dyno.tuning.shift_curve import load_engine_map, predict_shift_curve
    from dyno.tuning.tune import load_tune

    try:
        a = predict_shift_curve(load_tune(tune_path), load_engine_map(map_path), n_points=30).arrays()
    except (DynoError,) + _OPTIONAL_ERRORS as exc:
        notes.append(f"predicted shift curve not shown: {exc}")
        return None
    pairs = [(float(e), float(r)) for e, r in zip(a["engine_rpm"], a["ratio"]) if math.isfinite(e * r)]
    return {"engine_rpm": [e for e, _ in pairs], "ratio": [r for _, r in pairs]}


def _advised(run_dir: Path) -> dict | None:
    """The run library's record of advice on this run's tune file, if any (best effort)."""
    try:
        from dyno.library.advice import advised_for_run
        from dyno.library.index import runs_dir

        return advised_for_run(runs_dir(), run_dir)
    except Exception:  # noqa: BLE001  (an extra section: never stop the report)
        return None


def collect(run_dir, *, full_model: bool = False, now_s: float | None = None) -> ReportData:
    """Everything :func:`render_report` needs, read from ``run_dir`` (events are not loaded)."""
    from dyno import __version__
    from dyno.runlog.reader import load_run

    run_dir = Path(run_dir)
    run = load_run(run_dir, with_events=False)
    notes: list = []
    if run.torn:  # killed mid-write: say what the readers dropped
        notes.append(f"the run was killed mid-write; dropped a torn last record: {run.torn}")
    tune = run_dir / "tune.toml"
    return ReportData(
        run_dir=str(run_dir), meta=run.meta, documents=run.documents, calibration=run.calibration,
        engine_map=_engine_map(run.engine_map_path, notes) if run.engine_map_path else None,
        tune_text=tune.read_text(encoding="utf-8") if tune.exists() else None,
        model=_model(run.points, notes, full_model, Path(run_dir) / "tune.toml"), predicted_shift=_predicted_shift(run_dir, notes),
        advised=_advised(run_dir),
        generator_version=__version__, generated_unix_s=time.time() if now_s is None else now_s, notes=notes)


def write_report(run_dir, out=None, *, full_model: bool = False) -> Path:
    """Build the report of ``run_dir`` and write it to ``out`` (default ``RUN/report.html``)."""
    from dyno.fileio import write_atomic

    path = Path(out) if out is not None else Path(run_dir) / REPORT_NAME
    write_atomic(path, render_report(collect(run_dir, full_model=full_model)), mode=0o644)  # a page to share: readable by all
    return path
