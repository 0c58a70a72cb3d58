"""The systematic part of a point's efficiency uncertainty, stated beside the statistical CI.

``efficiency_ci95`` is the scatter of one window; it shrinks with measuring longer.  Two terms do not,
and they are shared by every point of a run (so they shift a whole curve, not one point):

* the **torque calibration**'s slope (efficiency ∝ torque ∝ 1/slope): its reproducibility, the relative
  standard deviation of the slopes in the calibration history (the rig's calibrations scatter more than
  one fit's own slope error says), combined with the entry's own fit error when its sample count is known;
* the **engine map**'s torque (efficiency ∝ 1/map power): a relative standard uncertainty stated in
  ``rig.toml [uncertainty] engine_map_rel`` (5 % by default: the shipped map is representative, not
  measured; a map measured on a dyno of stated accuracy allows less).

Each is given as a 95 % half-width (coverage factor 2), a fraction like ``efficiency``:
``efficiency_sys95_calibration``, ``efficiency_sys95_engine_map`` and, in quadrature, ``efficiency_sys95``.
"""

from __future__ import annotations

import math
import statistics


def calibration_rel_u(history, entry) -> float:
    """Relative standard uncertainty of the torque calibration's slope (see the module docstring)."""
    slopes = [e.slope_counts_per_nm for e in history if e.slope_counts_per_nm]
    spread = statistics.stdev(slopes) / statistics.fmean(slopes) if len(slopes) >= 2 else 0.0
    fit = 0.0
    n, r2 = getattr(entry, "n_samples", 0) or 0, getattr(entry, "r2", math.nan)
    if n > 2 and 0 < r2 < 1:  # relative standard error of a least-squares slope from R^2
        fit = math.sqrt((1.0 - r2) / ((n - 2) * r2))
    return math.hypot(spread, fit)


def point_systematic(point: dict, calibration_rel: float, engine_map_rel: float) -> dict:
    """The 95 % systematic half-widths of ``point``'s efficiency (NaN without an efficiency)."""
    eff = point.get("efficiency", math.nan)
    if not isinstance(eff, float) or not math.isfinite(eff):
        return {"efficiency_sys95": math.nan, "efficiency_sys95_calibration": math.nan,
                "efficiency_sys95_engine_map": math.nan}
    cal, emap = 2.0 * eff * calibration_rel, 2.0 * eff * engine_map_rel
    return {"efficiency_sys95": math.hypot(cal, emap), "efficiency_sys95_calibration": cal,
            "efficiency_sys95_engine_map": emap}
