"""Operating-range sweeps by continuation, and their tables and plots.

The thesis (Section 6.2) swept the radii from the 1:1 solution with an
artificially stiff belt and then relaxed EI point by point.  Here each point
is warm-started from its converged neighbour by a homotopy in all parameters
(:func:`dyno.model.solution.solve_point` with ``guess``), starting from a
solution near 1:1 and walking outwards in both directions, so no stored
starting solution is needed.  A point that does not converge is reported as
such (with the :class:`~dyno.errors.DidNotConverge` message) and the walk
continues from the last good solution.

This module does no file I/O: :func:`rows_to_csv` returns text and
:func:`plot_sweep` returns a matplotlib figure; the CLI writes them.
"""

from __future__ import annotations

import csv
import io
import math
import time
from dataclasses import replace

import numpy as np

from dyno.errors import MODEL_FAILURES
from dyno.model.params import ModelParams, OperatingPoint, TABLE_6_1, TABLE_6_1_POINT

DEFAULT_RATIO_RANGE = (1.74, 0.72)

CSV_COLUMNS = (
    "ratio",
    "converged",
    "r_primary_m",
    "r_secondary_m",
    "primary_speed_rpm",
    "primary_torque_nm",
    "slack_tension_n",
    "tight_tension_n",
    "secondary_speed_rpm",
    "secondary_torque_nm",
    "wrap_primary_deg",
    "wrap_secondary_deg",
    "axial_force_primary_n",
    "axial_force_secondary_n",
    "efficiency_speed",
    "efficiency_torque",
    "efficiency_overall",
    "min_sliding_primary_m_s",
    "min_sliding_secondary_m_s",
    "residual_max",
    "slip_threshold_m_s",
    "variant",
    "solve_s",
    "error",
)


def summary_row(summary: dict, op: OperatingPoint) -> dict:
    """Flatten a full-model summary into one CSV row."""
    return {
        "ratio": summary["ratio"],
        "converged": True,
        "r_primary_m": summary["radius_m"]["primary"],
        "r_secondary_m": summary["radius_m"]["secondary"],
        "primary_speed_rpm": summary["primary_speed_rpm"],
        "primary_torque_nm": summary["torque_nm"]["primary"],
        "slack_tension_n": summary["span_tension_n"]["slack"],
        "tight_tension_n": summary["span_tension_n"]["tight"],
        "secondary_speed_rpm": summary["secondary_speed_rpm"],
        "secondary_torque_nm": summary["torque_nm"]["secondary"],
        "wrap_primary_deg": summary["wrap_deg"]["primary"],
        "wrap_secondary_deg": summary["wrap_deg"]["secondary"],
        "axial_force_primary_n": summary["axial_force_n"]["primary"],
        "axial_force_secondary_n": summary["axial_force_n"]["secondary"],
        "efficiency_speed": summary["efficiency"]["speed"],
        "efficiency_torque": summary["efficiency"]["torque"],
        "efficiency_overall": summary["efficiency"]["overall"],
        "min_sliding_primary_m_s": summary["min_sliding_speed_m_s"]["primary"],
        "min_sliding_secondary_m_s": summary["min_sliding_speed_m_s"]["secondary"],
        "residual_max": summary["residual_max"],
        "slip_threshold_m_s": summary["slip_threshold_m_s"],
        "variant": summary["variant"],
        "solve_s": summary["solve_s"],
        "error": "",
    }


def failed_row(op: OperatingPoint, variant: str, slip_threshold_m_s: float, error: str) -> dict:
    row = {k: float("nan") for k in CSV_COLUMNS}
    row.update(ratio=op.ratio, converged=False, primary_speed_rpm=op.primary_speed_rpm,
               primary_torque_nm=op.primary_torque_nm, variant=variant, slip_threshold_m_s=slip_threshold_m_s,
               error=error)
    return row


def ratio_grid(n_points: int = 20, ratio_range=DEFAULT_RATIO_RANGE) -> np.ndarray:
    """Ratios evenly spaced in log(ratio) (the radii change about evenly)."""
    hi, lo = ratio_range
    return np.exp(np.linspace(math.log(hi), math.log(lo), n_points))


def sweep_ratios(
    ratios,
    params: ModelParams = TABLE_6_1,
    op: OperatingPoint = TABLE_6_1_POINT,
    *,
    variant: str = "corrected",
    slip_threshold_m_s: float = 1e-4,
    tol: float = 1e-3,
    start=None,
    friction_corner: float = 0.0,
    log=None,
):
    """Solve ``op`` at every ratio by continuation; returns ``(rows, solutions)`` in input order.

    ``start`` may be a converged :class:`~dyno.model.solution.BeltSolution`
    anywhere near the range; otherwise the point nearest 1:1 is solved from
    the geometric guess.  ``solutions[i]`` is None where row ``i`` failed.
    """
    from dyno.model.solution import solve_point

    ratios = [float(r) for r in ratios]
    order = np.argsort(np.abs(np.log(ratios)))
    first = int(order[0])
    rows: list = [None] * len(ratios)
    sols: list = [None] * len(ratios)

    def one(i, guess):
        op_i = replace(op, ratio=ratios[i])
        t0 = time.perf_counter()
        try:
            s = solve_point(params, op_i, variant=variant, slip_threshold_m_s=slip_threshold_m_s, tol=tol, guess=guess,
                            friction_corner=friction_corner)
        except MODEL_FAILURES as exc:
            rows[i] = failed_row(op_i, variant, slip_threshold_m_s, str(exc))
            if log:
                log(f"ratio {ratios[i]:.4f}: FAILED after {time.perf_counter() - t0:.1f} s")
            return None
        rows[i] = summary_row(s.summary, op_i)
        sols[i] = s
        if log:
            log(f"ratio {ratios[i]:.4f}: eta={s.summary['efficiency']['overall']:.4f} in {time.perf_counter() - t0:.1f} s")
        return s

    base = one(first, start)
    if base is None and start is None:
        return rows, sols
    # Walk outwards from the first point in both directions.
    for direction in (1, -1):
        guess = base if base is not None else start
        idx = sorted(range(len(ratios)), key=lambda j: ratios[j], reverse=direction < 0)
        pos = idx.index(first)
        for j in idx[pos + 1:]:
            s = one(j, guess)
            if s is not None:
                guess = s
    return rows, sols


def sweep_operating_range(n_points: int = 20, params: ModelParams = TABLE_6_1, op: OperatingPoint = TABLE_6_1_POINT,
                          ratio_range=DEFAULT_RATIO_RANGE, **kwargs):
    """The thesis's operating-range sweep (1.74:1 to 0.72:1 by default)."""
    return sweep_ratios(ratio_grid(n_points, ratio_range), params, op, **kwargs)


def rows_to_csv(rows, extra_columns: dict | None = None) -> str:
    """CSV text of sweep rows (``extra_columns``: constant columns prepended, e.g. a study parameter)."""
    extra = extra_columns or {}
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(extra) + list(CSV_COLUMNS), extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow({**extra, **row})
    return buf.getvalue()


def plot_sweep(series: dict, title: str = ""):
    """Figure with efficiencies and axial forces vs ratio; ``series`` maps a label to rows."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for label, rows in series.items():
        ok = [r for r in rows if r and r["converged"]]
        x = [r["ratio"] for r in ok]
        axes[0].plot(x, [r["efficiency_overall"] for r in ok], "o-", label=f"{label} overall")
        axes[1].plot(x, [r["efficiency_speed"] for r in ok], "s--", label=f"{label} speed")
        axes[1].plot(x, [r["efficiency_torque"] for r in ok], "^-", label=f"{label} torque")
        axes[2].plot(x, [r["axial_force_primary_n"] for r in ok], "o-", label=f"{label} primary")
        axes[2].plot(x, [r["axial_force_secondary_n"] for r in ok], "s--", label=f"{label} secondary")
    for ax, ylabel in zip(axes, ("overall efficiency", "speed / torque efficiency", "axial force [N]")):
        ax.set_xlabel("ratio R_S/R_P")
        ax.set_ylabel(ylabel)
        ax.invert_xaxis()
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
