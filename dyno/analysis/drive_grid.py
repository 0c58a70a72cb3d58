"""The drive grid's table (pure): throttle x secondary-speed cells from the logged cells and the points.

The live run and ``dyno replay`` both call :func:`grid_table` -- the replay on its re-processed points --
so the grid follows the points (a replay with another engine map re-states every cell's efficiency).
"""

from __future__ import annotations

import math

#: what each cell carries from its point (null when the cell has no point, or the value is undefined)
CELL_KEYS = ("rpm_primary", "rpm_secondary", "ratio", "torque_secondary_nm", "power_out_w", "power_in_w",
             "efficiency", "efficiency_ci95", "efficiency_sys95", "efficiency_true")


def _num(v):
    return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v


def grid_table(cells, points) -> dict:
    """``{"throttles", "setpoints_rpm", "cells"}``: one cell per (throttle, setpoint) in run order.

    A cell with a point has its values and ``reason`` null, or the point's ``efficiency_reason`` when the
    efficiency is undefined; a cell without a point has ``index`` null and the reason it has none.
    """
    by_index = {p.get("index"): p for p in points}
    out = []
    for c in cells:
        p = by_index.get(c.get("index")) if c.get("index") is not None else None
        row = {"throttle_frac": c["throttle_frac"], "setpoint_rpm": c["setpoint_rpm"],
               "index": c.get("index") if p is not None else None}
        row.update({k: _num(p.get(k)) if p is not None else None for k in CELL_KEYS})
        row["reason"] = (p.get("efficiency_reason") if p is not None else
                         (c.get("reason") or "no point recorded for this cell"))
        out.append(row)
    throttles = list(dict.fromkeys(c["throttle_frac"] for c in cells))
    setpoints = sorted({c["setpoint_rpm"] for c in cells}, reverse=True)
    return {"throttles": throttles, "setpoints_rpm": setpoints, "cells": out}
