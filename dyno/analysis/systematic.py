r"""The systematic part of a point's efficiency uncertainty, stated beside the statistical CI.

``efficiency_ci95`` is the scatter of one window; it shrinks with measuring longer.  Two terms do not,
and they are shared by every point of a run (so they shift a whole curve, not one point):

* the **torque calibration**'s slope (efficiency ∝ torque ∝ 1/slope): its reproducibility, the relative
  standard deviation of the slopes in the calibration history (the rig's calibrations scatter more than
  one fit's own slope error says), combined with the entry's own fit error when its sample count is known;
* the **engine map**'s torque (efficiency ∝ 1/map power): a relative standard uncertainty stated in
  ``rig.toml [uncertainty] engine_map_rel`` (5 % by default: the shipped map is representative, not
  measured; a map measured on a dyno of stated accuracy allows less).

* the **air** (efficiency ∝ CF, the SAE J1349 factor the map is taken to the run's day by): what the
  day is known to (a BME280 or a given reading), or, for a run *uncorrected* (no air known), a bound
  over a plausible day (:mod:`dyno.analysis.air`).

Each is given as a 95 % half-width (coverage factor 2), a fraction like ``efficiency``:
``efficiency_sys95_calibration``, ``efficiency_sys95_engine_map``, ``efficiency_sys95_air`` and, in
quadrature, ``efficiency_sys95``.  The point's total, ``efficiency_u95``, combines it with the
statistical ``efficiency_ci95``:

.. math:: U_{95} = \sqrt{CI_{95}^2 + \sum_k (2\,\eta\,u_{k,rel})^2}

and ``efficiency_u95_terms`` lists each part's half-width (``statistical``, ``calibration``,
``engine_map``, ``air``).  The systematic parts are one draw per run: every point of a run shares its
engine, sensor and day, so they shift a whole curve together (judged over many runs, never one).
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


SYSTEMATIC_KEYS = ("efficiency_sys95", "efficiency_sys95_calibration", "efficiency_sys95_engine_map",
                   "efficiency_sys95_air", "efficiency_u95", "efficiency_u95_terms")


def calibration_rel_for(calibration_rel: float, point: dict, tare: dict | None) -> float:
    """The calibration term at this point: the slope's, and the tare's (the zero read at rest before GO
    carries its own standard uncertainty ``u_nm``, relative to this point's torque)."""
    torque = point.get("torque_secondary_nm", math.nan)
    u_nm = (tare or {}).get("u_nm", 0.0) or 0.0
    if not (isinstance(torque, float) and math.isfinite(torque) and abs(torque) > 0.0) or not u_nm:
        return calibration_rel
    return math.hypot(calibration_rel, u_nm / abs(torque))


def point_systematic(point: dict, calibration_rel: float, engine_map_rel: float, air_rel: float = 0.0) -> dict:
    """The 95 % systematic half-widths of ``point``'s efficiency and its total ``efficiency_u95``.

    NaN (and no terms) without an efficiency.  ``air_rel`` 0 is a run from before the air was stated.
    """
    eff = point.get("efficiency", math.nan)
    if not isinstance(eff, float) or not math.isfinite(eff):
        return {"efficiency_sys95": math.nan, "efficiency_sys95_calibration": math.nan,
                "efficiency_sys95_engine_map": math.nan, "efficiency_sys95_air": math.nan,
                "efficiency_u95": math.nan, "efficiency_u95_terms": None}
    cal, emap, air = 2.0 * eff * calibration_rel, 2.0 * eff * engine_map_rel, 2.0 * eff * (air_rel or 0.0)
    sys95 = math.sqrt(cal * cal + emap * emap + air * air)
    ci = point.get("efficiency_ci95", math.nan)
    ci = ci if isinstance(ci, float) and math.isfinite(ci) else 0.0
    return {"efficiency_sys95": sys95, "efficiency_sys95_calibration": cal, "efficiency_sys95_engine_map": emap,
            "efficiency_sys95_air": air, "efficiency_u95": math.hypot(ci, sys95),
            "efficiency_u95_terms": {"statistical": ci, "calibration": cal, "engine_map": emap, "air": air}}
