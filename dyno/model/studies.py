"""The thesis's parameter studies (Section 7) as operating-range sweeps.

* ``sheave_angle``: 8, 12, 16 deg, the same belt, so k scales with tan(beta) (eq 7.1);
* ``bending_stiffness``: 0.025, 0.2, 0.5 N*m^2;
* ``slack_tension``: 50, 100, 200 N slack-span tractive tension;
* ``friction``: 0.3, 0.4, 0.5.

Each parameter value is reached from the baseline solution by homotopy (a
warm start) and then swept over the ratio range.
"""

from __future__ import annotations

from dataclasses import replace

from dyno.errors import MODEL_FAILURES
from dyno.model import sweep
from dyno.model.params import ModelParams, OperatingPoint, TABLE_6_1, TABLE_6_1_POINT, bad_input

DEFAULT_VALUES = {
    "sheave_angle": (8.0, 12.0, 16.0),
    "bending_stiffness": (0.025, 0.2, 0.5),
    "slack_tension": (50.0, 100.0, 200.0),
    "friction": (0.3, 0.4, 0.5),
}


def study_case(name: str, value: float, base_params: ModelParams, op: OperatingPoint):
    if name == "sheave_angle":
        return base_params.with_sheave_angle(value), op
    if name == "bending_stiffness":
        return base_params.with_belt(bending_stiffness_nm2=value), op
    if name == "friction":
        return base_params.with_belt(friction_coefficient=value), op
    if name == "slack_tension":
        return base_params, replace(op, slack_tension_n=value, primary_axial_force_n=None)
    raise bad_input("study", f"one of {', '.join(DEFAULT_VALUES)}, got {name!r}")


def run_study(
    name: str,
    values=None,
    base_params: ModelParams = TABLE_6_1,
    op: OperatingPoint = TABLE_6_1_POINT,
    n_points: int = 10,
    ratio_range=sweep.DEFAULT_RATIO_RANGE,
    variant: str = "corrected",
    slip_threshold_m_s: float = 1e-4,
    tol: float = 1e-3,
    log=None,
    *,
    executor=None,
    cache_dir=None,
    use_cache: bool = True,
    progress=None,
) -> dict:
    """Returns ``{"name", "values", "series": {value: rows}, "tasks": {"computed", "cached"}}``.

    One task per value (:mod:`dyno.model.study_tasks`), run by ``executor`` (default: in this process),
    each warm-started by homotopy from the baseline's solution at 1:1 (solved here, only if a value is
    not in the cache).
    """
    from dyno.model.executor import InlineExecutor
    from dyno.model.study_tasks import SweepTask, run_tasks, study_cache_dir, task_key

    if name not in DEFAULT_VALUES:
        raise bad_input("study", f"one of {', '.join(DEFAULT_VALUES)}, got {name!r}")
    values = tuple(DEFAULT_VALUES[name] if values is None else values)
    ratios = tuple(float(r) for r in sweep.ratio_grid(n_points, ratio_range))
    tasks = []
    for value in values:
        params_v, op_v = study_case(name, value, base_params, op)
        tasks.append(SweepTask(f"{name}={value:g}", params_v, op_v, ratios, variant, slip_threshold_m_s, tol,
                               homotopy=True))
    cache = study_cache_dir(cache_dir)
    if not (use_cache and all((cache / f"{task_key(t)}.json").is_file() for t in tasks)):
        from dyno.model.solution import solve_point

        try:
            base = solve_point(base_params, replace(op, ratio=1.0), variant=variant,
                               slip_threshold_m_s=slip_threshold_m_s, tol=tol)
            tasks = [replace(t, guess=base) for t in tasks]
        except MODEL_FAILURES:
            pass  # each value then starts from its own geometric guess

    def report(done, total, label, cached):
        if log:
            log(f"{label}: {'cached' if cached else 'solved'} ({done}/{total})")
        if progress:
            progress(done, total, label, cached)

    rows, counts = run_tasks(tasks, executor or InlineExecutor(), cache_dir=cache_dir, use_cache=use_cache,
                             progress=report)
    return {"name": name, "values": values, "series": dict(zip(values, rows)), "tasks": counts}


def run_sweep(n_points: int = 20, params: ModelParams = TABLE_6_1, op: OperatingPoint = TABLE_6_1_POINT,
              ratio_range=sweep.DEFAULT_RATIO_RANGE, variant: str = "corrected", slip_threshold_m_s: float = 1e-4,
              tol: float = 1e-3, *, executor=None, cache_dir=None, use_cache: bool = True, progress=None):
    """The operating-range sweep as two tasks, one per side of its point nearest 1:1 (both walk outwards
    from that point's solution, solved here first).  Returns ``(rows in grid order, {"computed", "cached"})``."""
    import numpy as np

    from dyno.model.executor import InlineExecutor
    from dyno.model.study_tasks import SweepTask, run_tasks, study_cache_dir, task_key

    ratios = [float(r) for r in sweep.ratio_grid(n_points, ratio_range)]
    f = int(np.argmin(np.abs(np.log(ratios))))
    sides = [tuple(ratios[:f + 1]), tuple(ratios[f:])]
    tasks = [SweepTask(label, params, op, side, variant, slip_threshold_m_s, tol)
             for label, side in zip(("high ratios", "low ratios"), sides)]
    cache = study_cache_dir(cache_dir)
    if not (use_cache and all((cache / f"{task_key(t)}.json").is_file() for t in tasks)):
        from dyno.model.solution import solve_point

        try:
            first = solve_point(params, replace(op, ratio=ratios[f]), variant=variant,
                                slip_threshold_m_s=slip_threshold_m_s, tol=tol)
            tasks = [replace(t, guess=first) for t in tasks]
        except MODEL_FAILURES:
            pass  # each side from the geometric guess (and reports the failure at its first point)
    (high, low), counts = run_tasks(tasks, executor or InlineExecutor(), cache_dir=cache_dir,
                                    use_cache=use_cache, progress=progress)
    return high + low[1:], counts


def study_csv(result: dict) -> str:
    parts = []
    for i, (value, rows) in enumerate(result["series"].items()):
        text = sweep.rows_to_csv(rows, {result["name"]: value})
        parts.append(text if i == 0 else text.split("\n", 1)[1])
    return "".join(parts)
