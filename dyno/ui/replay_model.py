"""The replay viewer's logic (pure apart from reading runs and writing exports; no Textual).

Re-processing goes through :func:`dyno.runlog.replay.replay`, the same
``reduce_point`` the live controller used, so with the run's own calibration
and map the points are the logged ones.  Exports: CSV through
:func:`dyno.runlog.replay.export` (points + raw streams), PNG with matplotlib on the
Agg backend (no display over SSH), imported only when a PNG is asked for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dyno.protocol import v1


@dataclass
class ReplayRun:
    run_dir: Path
    result: dict  # dyno.runlog.replay.replay(...)
    run: object  # dyno.runlog.reader.Run (raw streams)
    calibration_path: Path | None = None
    engine_map_path: Path | None = None
    label: str = ""

    @property
    def points(self) -> list:
        return self.result["points"]


@dataclass
class ReplaySet:
    runs: list = field(default_factory=list)

    @classmethod
    def load(cls, run_dirs, calibration_path=None, engine_map_path=None) -> "ReplaySet":
        out = cls()
        for d in run_dirs:
            out.runs.append(load_replay(d, calibration_path, engine_map_path))
        return out

    def reprocess(self, i: int, calibration_path=None, engine_map_path=None) -> ReplayRun:
        """Re-process run ``i`` with another calibration history and/or engine map (None keeps the current)."""
        old = self.runs[i]
        cal = calibration_path if calibration_path is not None else old.calibration_path
        em = engine_map_path if engine_map_path is not None else old.engine_map_path
        self.runs[i] = load_replay(old.run_dir, cal, em)
        return self.runs[i]


def load_replay(run_dir, calibration_path=None, engine_map_path=None) -> ReplayRun:
    from dyno.runlog.replay import replay
    from dyno.runlog.reader import load_run

    run_dir = Path(run_dir)
    result = replay(run_dir, calibration_path, engine_map_path)
    cal = f" cal {Path(calibration_path).name}" if calibration_path else ""
    em = f" map {Path(engine_map_path).name}" if engine_map_path else ""
    return ReplayRun(run_dir, result, load_run(run_dir), Path(calibration_path) if calibration_path else None,
                     Path(engine_map_path) if engine_map_path else None, label=f"{run_dir.name}{cal}{em}")


def finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def efficiency_series(points) -> tuple[list, list, list]:
    """(secondary rpm, efficiency %, standard error %) of the points with an efficiency."""
    good = [p for p in points if finite(p.get("efficiency")) and finite(p.get("rpm_secondary"))]
    return ([p["rpm_secondary"] for p in good], [p["efficiency"] * 100 for p in good],
            [(p.get("efficiency_sem") or 0.0) * 100 if finite(p.get("efficiency_sem")) else 0.0 for p in good])


def shift_series(points) -> tuple[list, list]:
    good = [p for p in points if finite(p.get("rpm_primary")) and finite(p.get("rpm_secondary"))]
    return [p["rpm_secondary"] for p in good], [p["rpm_primary"] for p in good]


def point_streams(run, point: dict, margin_s: float = 1.0) -> dict:
    """Raw streams around one point: ADC counts and per-period rpm over the point's window +- ``margin_s``.

    Times in s relative to the point's start.
    """
    t0, t1 = int(point["t_start_us"]), int(point["t_end_us"])
    a, b = t0 - int(margin_s * 1e6), t1 + int(margin_s * 1e6)
    s = run.streams
    t_adc, codes, status = s.adc_window(a, b)
    out = {"adc_t_s": ((t_adc - t0) / 1e6).tolist(), "adc_counts": codes.tolist(),
           "adc_error": int(((status & v1.ADC_STATUS_ERR) != 0).sum()), "window_s": (t1 - t0) / 1e6}
    for name, ch in (("primary", v1.CH_PRIMARY), ("secondary", v1.CH_SECONDARY)):
        e = s.edge_window(ch, a, b)
        if e.size >= 2:
            per = np.diff(e) / 1e6
            out[f"{name}_t_s"] = ((e[1:] - t0) / 1e6).tolist()
            out[f"{name}_rpm"] = (60.0 / per).tolist()
        else:
            out[f"{name}_t_s"], out[f"{name}_rpm"] = [], []
    return out


def export_csv(rr: ReplayRun, out_dir=None) -> list[Path]:
    """points.csv (re-processed) and the raw streams, into ``out_dir`` (default ``<run>/export``)."""
    from dyno.runlog.replay import export

    return export(rr.run_dir, out_dir, calibration_path=rr.calibration_path, engine_map_path=rr.engine_map_path)


def export_png(rs: ReplaySet, path, ideal_engine_rpm: float | None = None) -> Path:
    """Efficiency and shift-curve plots of every run, overlaid, as one PNG (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg", force=True)  # no display over SSH; must precede pyplot
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, (ax_e, ax_s) = plt.subplots(1, 2, figsize=(11, 4.5), dpi=100)
    for rr in rs.runs:
        x, y, e = efficiency_series(rr.points)
        ax_e.errorbar(x, y, yerr=e, fmt="o", capsize=3, label=rr.label)
        xs, ys = shift_series(rr.points)
        ax_s.plot(xs, ys, "o-", label=rr.label)
    if ideal_engine_rpm and math.isfinite(ideal_engine_rpm):
        ax_s.axhline(ideal_engine_rpm, color="green", ls="--", label=f"ideal {ideal_engine_rpm:.0f} rpm (peak power)")
    ax_e.set(xlabel="secondary speed, rpm", ylabel="efficiency, %", title="CVT efficiency")
    ax_s.set(xlabel="secondary speed, rpm", ylabel="engine speed, rpm", title="shift curve")
    for ax in (ax_e, ax_s):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp)
    plt.close(fig)
    tmp.replace(path)  # a reader never sees half a PNG
    return path


def ideal_rpm_for(rr: ReplayRun) -> float:
    from dyno.analysis.engine_map import load_engine_map
    from dyno.analysis.live import ideal_engine_rpm

    src = rr.engine_map_path or rr.run.engine_map_path
    try:
        return ideal_engine_rpm(load_engine_map(src)) if src else math.nan
    except Exception:  # a map that cannot be read only loses the reference line
        return math.nan


def predicted_shift_series(run_dir, n_points: int = 30):
    """The tune's predicted shift curve (closed-form belt thrusts) for a run that stored its tune.

    Returns ``(secondary_rpm, engine_rpm)`` lists, or ``None`` when the run has no
    ``tune.toml`` or the prediction fails (the viewer then just shows the measurement).
    """
    run_dir = Path(run_dir)
    tune_path, map_path = run_dir / "tune.toml", run_dir / "engine_map.csv"
    if not (tune_path.exists() and map_path.exists()):
        return None
    from dyno.errors import DynoError
    from dyno.tuning.shift_curve import load_engine_map, predict_shift_curve
    from dyno.tuning.tune import load_tune

    try:
        curve = predict_shift_curve(load_tune(tune_path), load_engine_map(map_path), n_points=n_points)
    except (DynoError, ValueError, ArithmeticError):
        return None
    a = curve.arrays()
    return a["secondary_rpm"].tolist(), a["engine_rpm"].tolist()


def compare_with_first(rs: ReplaySet, i: int, step_rpm: float = 200.0) -> dict:
    """Run ``i`` against run 0 as ``dyno compare`` does (:func:`dyno.library.compare.compare`).

    Uses the viewer's (possibly re-processed) points. Raises ValueError when the two
    runs cannot be compared (too few points, no common secondary-speed range).
    """
    from dyno.library.compare import compare
    from dyno.library.index import key
    from dyno.library.summary import read_run_files, run_row

    runs = []
    for rr in (rs.runs[0], rs.runs[i]):
        files = read_run_files(rr.run_dir)
        runs.append({"name": rr.label, "row": run_row(files, key(rr.run_dir)), "points": rr.points,
                     "tune": files["tune"]["data"] if files["tune"] else None, "meta": files["meta"]})
    return compare(runs, step_rpm=step_rpm)
