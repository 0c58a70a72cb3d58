import pytest
"""The drive grid's table (pure): cells join their points; a cell without a point keeps its reason; a point
without an efficiency gives the cell its efficiency_reason; NaN becomes null."""

import math

from dyno.analysis.drive_grid import grid_table

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def test_cells_join_points_and_keep_reasons():
    cells = [{"throttle_frac": 1.0, "setpoint_rpm": 3000.0, "index": 0, "reason": None},
             {"throttle_frac": 1.0, "setpoint_rpm": 4000.0, "index": None, "reason": "cannot hold"},
             {"throttle_frac": 0.6, "setpoint_rpm": 4000.0, "index": None, "reason": "unreachable at throttle 0.60"},
             {"throttle_frac": 0.6, "setpoint_rpm": 3000.0, "index": 1, "reason": None},
             {"throttle_frac": 0.6, "setpoint_rpm": 2000.0, "index": 7, "reason": None}]  # its point is missing
    points = [{"index": 0, "torque_secondary_nm": 15.0, "efficiency": 0.88, "efficiency_ci95": 0.007,
               "efficiency_reason": None, "ratio": 0.95},
              {"index": 1, "torque_secondary_nm": 15.1, "efficiency": math.nan, "efficiency_ci95": math.nan,
               "efficiency_reason": "no engine-map curve at throttle 0.60", "ratio": 0.96}]
    g = grid_table(cells, points)
    assert g["throttles"] == [1.0, 0.6] and g["setpoints_rpm"] == [4000.0, 3000.0, 2000.0]
    c = g["cells"]
    assert c[0]["efficiency"] == 0.88 and c[0]["reason"] is None and c[0]["index"] == 0
    assert c[1]["index"] is None and c[1]["torque_secondary_nm"] is None and c[1]["reason"] == "cannot hold"
    assert c[2]["reason"].startswith("unreachable")
    assert c[3]["torque_secondary_nm"] == 15.1 and c[3]["efficiency"] is None and c[3]["efficiency_ci95"] is None
    assert c[3]["reason"] == "no engine-map curve at throttle 0.60"
    assert c[4]["index"] is None and c[4]["reason"] == "no point recorded for this cell"
