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


def _model(points: list, notes: list, full: bool = False, tune_path: Path | None = None) -> dict | None:
    """The belt model at each plotted point: the full model (thesis BVP) when asked or already in the model
    cache, else its closed form (instant, creep loss only: an upper bound).  Each point's input is the
    slip-consistent inverse's (geometric ratio and the run's tune's clamp, ``overlay_inputs``)."""
    from dyno.ui.live_model import overlay_inputs

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
    rpm_s = [x for x, _ in pairs]
    ops = [op for _, op in pairs]
    if not ops:
        return None
    from dyno.model.overlay import all_cached, predict_overlay

    # the full model when asked, or when the UI's overlay already solved these points; else instant
    tier = "full" if full or all_cached(ops) else "closed_form"
    try:
        pred = predict_overlay(ops, tier=tier, time_limit_s=20.0)
    except _OPTIONAL_ERRORS as exc:
        notes.append(f"belt-model overlay not shown: {exc}")
        return None
    pairs = sorted((x, float(r["efficiency"]["overall"])) for x, r in zip(rpm_s, pred) if r.get("converged"))
    if len(pairs) < len(ops):
        notes.append(f"belt model ({tier}): {len(ops) - len(pairs)} of {len(ops)} points did not converge")
    if not pairs:
        return None
    label = ("full model (thesis BVP), Table 6.1 belt" if tier == "full" else
             "closed form, Table 6.1 belt: creep loss only, an upper bound; `dyno report RUN --model full` "
             "solves the full model")
    return {"rpm_secondary": [x for x, _ in pairs], "efficiency": [e for _, e in pairs], "label": label,
            "tier": tier}


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
        generator_version=__version__, generated_unix_s=time.time() if now_s is None else now_s, notes=notes)


def write_report(run_dir, out=None, *, full_model: bool = False) -> Path:
    """Build the report of ``run_dir`` and write it to ``out`` (default ``RUN/report.html``)."""
    from dyno.fileio import write_atomic

    path = Path(out) if out is not None else Path(run_dir) / REPORT_NAME
    write_atomic(path, render_report(collect(run_dir, full_model=full_model)), mode=0o644)  # a page to share: readable by all
    return path
