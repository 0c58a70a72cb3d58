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
) -> dict:
    """Returns ``{"name", "values", "series": {value: rows}}``."""
    from dyno.model.solution import solve_point

    if name not in DEFAULT_VALUES:
        raise bad_input("study", f"one of {', '.join(DEFAULT_VALUES)}, got {name!r}")
    values = tuple(DEFAULT_VALUES[name] if values is None else values)
    base = None
    try:
        base = solve_point(base_params, replace(op, ratio=1.0), variant=variant,
                           slip_threshold_m_s=slip_threshold_m_s, tol=tol)
    except MODEL_FAILURES:
        base = None  # each value then starts from its own geometric guess
    series = {}
    for value in values:
        params_v, op_v = study_case(name, value, base_params, op)
        start = None
        if base is not None:
            try:
                start = solve_point(params_v, replace(op_v, ratio=1.0), variant=variant,
                                    slip_threshold_m_s=slip_threshold_m_s, tol=tol, guess=base)
            except MODEL_FAILURES:
                start = None
        if log:
            log(f"{name}={value:g}")
        rows, _ = sweep.sweep_operating_range(n_points, params_v, op_v, ratio_range=ratio_range, variant=variant,
                                              slip_threshold_m_s=slip_threshold_m_s, tol=tol, start=start, log=log)
        series[value] = rows
    return {"name": name, "values": values, "series": series}


def study_csv(result: dict) -> str:
    parts = []
    for i, (value, rows) in enumerate(result["series"].items()):
        text = sweep.rows_to_csv(rows, {result["name"]: value})
        parts.append(text if i == 0 else text.split("\n", 1)[1])
    return "".join(parts)
