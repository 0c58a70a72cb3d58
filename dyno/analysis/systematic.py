r"""The systematic part of a point's efficiency uncertainty, stated beside the statistical CI.

``efficiency_ci95`` is the scatter of one window; it shrinks with measuring longer.  Four terms do not,
and they are shared by every point of a run (so they shift a whole curve, not one point):

* the **torque calibration**'s slope (efficiency ∝ torque ∝ 1/slope): its reproducibility, the relative
  standard deviation of the slopes in the calibration history (the rig's calibrations scatter more than
  one fit's own slope error says), combined with the entry's own fit error when its sample count is known;
* the **engine map**'s torque (efficiency ∝ 1/map power): the relative standard uncertainty the map file
  states (``# stated_u_rel``: 10 % in the shipped representative map; a measured map states its
  measurement's), else ``rig.toml [uncertainty] engine_map_rel`` (:mod:`dyno.analysis.u95_terms`);
  a map not measured on this engine never less than real engines' spread about maps (9.8 %).
* the **engine's wear**, for a map not measured on this engine: a map is a new engine's (or a class's), and
  an engine in service only loses power to it (rings, valves, carbon, a loaded filter), so the truth is the
  reading times ``1/(1 − w)``, ``w`` uniform on ``[0, w_max]`` (``engine_wear_max_frac`` in the run's
  ``uncertainty``: 14 %, the far end of the one real engine's 4–14 % under its map,
  ``u95_terms.ENGINE_WEAR_MAX_FRAC``); one-sided like the driveline's, its ``engine_wear`` entry
  ``η·(1/(1 − w_max) − 1)``.  A map measured on this engine has none.

* the **air** (efficiency ∝ CF, the SAE J1349 factor the map is taken to the run's day by): what the
  day is known to (a BME280 or a given reading), or, for a run *uncorrected* (no air known), the factor's
  distribution over a plausible day (:mod:`dyno.analysis.air`; ``efficiency_sys95_air`` is half its 95 %
  range, the interval below its quantiles).

Each is given as a 95 % half-width (coverage factor 2), a fraction like ``efficiency``:
``efficiency_sys95_calibration``, ``efficiency_sys95_engine_map``, ``efficiency_sys95_air``, and
``efficiency_u95_terms`` lists each part's half-width (``statistical``, ``calibration``, ``engine_map``,
``air``, ``driveline``) so a reader sees which dominates.

* the **driveline** between the CVT and the gauge (chain, bearings; ``rig.toml [driveline]``): a loss only
  ever lowers the reading, so its term is one-sided: the truth is the reading times ``1/(1 − L)``, ``L``
  uniform on ``[0, L_max]``, ``L_max = loss_max_frac + drag_max_nm/|T_s|`` (the chain's share of the load
  and the bearings' drag, :func:`driveline_bound`); its ``driveline`` entry is that upward extent,
  ``η·(1/(1 − L_max) − 1)``.  A coast-down's ``driven_loss.json`` measures the loss instead
  (``efficiency_loss_corrected``, whose interval carries the correction's own residual, not this term).

The **interval** ``efficiency_interval95 = [low, high]`` is what the truth is said to lie in at 95 %:
the 2.5/97.5 % quantiles of :math:`\eta\,A\,D\,(1+\varepsilon)`, with ``A`` the uncorrected air's factor
(its distribution over the plausible day, :func:`dyno.analysis.air.uncorrected_factors`; 1 when the day
is known), ``D`` the one-sided terms' ``1/((1 − L)(1 − w))`` (the driveline's, the engine's wear) and ``ε`` normal with sd half the symmetric terms'
quadrature over η (k = 2).  It is asymmetric where a term is, and clipped to [0, 1] (an efficiency
cannot exceed 1).  Every efficiency variant ``K`` carries ``K_interval95`` the same way
(:func:`variant_interval95`).

The interval is the point's **one** 95 % statement.  ``efficiency_u95`` is its half-width,
``(high − low)/2`` (:func:`half_width`), so ``±U95`` never says something else than the interval (adding the
one-sided driveline in quadrature as if it were symmetric did); ``efficiency_sys95`` is the half-width of the
interval the systematic terms alone give (no ``efficiency_ci95``).  The systematic parts are one draw per run: every point of a run shares its
engine, sensor and day, so they shift a whole curve together (judged over many runs, never one).
"""

from __future__ import annotations

import math
import statistics
from statistics import NormalDist

#: The interval's quadrature: the normal's and the driveline's equal-probability midpoints.
_Z = tuple(NormalDist().inv_cdf((i + 0.5) / 24) for i in range(24))
_N_DRIVELINE = 12


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
                   "efficiency_sys95_air", "efficiency_sys95_driveline", "efficiency_u95", "efficiency_u95_terms",
                   "efficiency_interval95")


def interval95(value: float, sym95: float, air_factors=None, driveline_max_frac: float = 0.0,
               wear_max_frac: float = 0.0) -> list | None:
    """``[low, high]``: the 95 % interval of the truth about a reading ``value`` (see the module docstring).

    ``sym95``: the symmetric terms' 95 % half-width (quadrature, absolute); ``air_factors``: equal-probability
    quantiles of the uncorrected air's factor (None: the day is known); ``driveline_max_frac``: the
    one-sided loss bound; ``wear_max_frac``: the engine's one-sided wear bound (a map not measured on this
    engine).  Clipped to [0, 1].  None for a value that is not a finite number.
    """
    if not (isinstance(value, (int, float)) and math.isfinite(value)):
        return None
    sym95 = sym95 if isinstance(sym95, (int, float)) and math.isfinite(sym95) else 0.0
    no_air = air_factors is None or len(air_factors) == 0
    if value <= 0.0 or (no_air and not driveline_max_frac and not wear_max_frac):
        lo, hi = value - sym95, value + sym95
    else:
        import numpy as np

        a = np.asarray((1.0,) if no_air else air_factors, dtype=float)
        mid = (np.arange(_N_DRIVELINE) + 0.5) / _N_DRIVELINE
        d = 1.0 / (1.0 - float(driveline_max_frac or 0.0) * mid)
        if wear_max_frac:  # two independent one-sided factors: their product's equal-probability midpoints
            d = np.quantile(np.outer(d, 1.0 / (1.0 - float(wear_max_frac) * mid)).ravel(), mid)
        e = 1.0 + np.asarray(_Z) * (0.5 * sym95 / value)
        r = (a[:, None, None] * d[None, :, None] * e[None, None, :]).ravel()
        q_lo, q_hi = np.quantile(r, (0.025, 0.975))
        lo, hi = value * float(q_lo), value * float(q_hi)
    return [max(0.0, lo), min(1.0, hi)]


def half_width(interval) -> float:
    """Half the width of a ``[low, high]`` interval: the ``±U95`` that states the same as it; NaN without one."""
    if not interval or len(interval) != 2 or not all(isinstance(v, (int, float)) and math.isfinite(v)
                                                      for v in interval):
        return math.nan
    return 0.5 * (float(interval[1]) - float(interval[0]))


def driveline_bound(point: dict | None, unc: dict | None) -> float:
    """The driveline's largest loss at ``point``, a fraction of what the gauge reads: the load-proportional
    part (``driveline_loss_max_frac``: the chain) plus the bearings' and seals' drag torque
    (``driveline_drag_max_nm``, at the secondary) over the point's torque — a drag is a larger share at light
    load.  At most 0.5; the fraction alone without a finite torque."""
    unc = unc or {}
    frac, drag = float(unc.get("driveline_loss_max_frac") or 0.0), float(unc.get("driveline_drag_max_nm") or 0.0)
    t = (point or {}).get("torque_secondary_nm")
    if drag and isinstance(t, (int, float)) and math.isfinite(t) and abs(t) > 0.0:
        frac += drag / abs(t)
    return min(0.5, frac)


def interval_basis(unc: dict | None, point: dict | None = None) -> dict:
    """The interval's asymmetric inputs from a run's ``uncertainty`` record (meta.json): the uncorrected air's
    factor quantiles (``air_day``: the site's ``altitude_m`` when the air is unknown, absent when known) and
    the driveline's bound at ``point`` (:func:`driveline_bound`) and the engine's wear bound (a map not
    measured on this engine)."""
    from dyno.analysis.air import uncorrected_factors

    unc = unc or {}
    day = unc.get("air_day")
    return {"air_factors": uncorrected_factors(day.get("altitude_m")) if isinstance(day, dict) else None,
            "driveline_max_frac": driveline_bound(point, unc),
            "wear_max_frac": float(unc.get("engine_wear_max_frac") or 0.0)}


def run_basis(ambient: dict | None, rig_cfg) -> dict:
    """The ``uncertainty`` record's interval inputs (as the composition root states them in meta.json) from a
    run's ``ambient`` and its rig file: for code that holds the run's result, not its meta."""
    amb, drv = getattr(rig_cfg, "ambient", None), getattr(rig_cfg, "driveline", None)
    known = (ambient or {}).get("j1349_factor") is not None
    return {"air_day": None if known else {"altitude_m": getattr(amb, "altitude_m", None)},
            "driveline_loss_max_frac": getattr(drv, "loss_max_frac", 0.0),
            "driveline_drag_max_nm": getattr(drv, "drag_max_nm", 0.0)}


def variant_interval95(value, point: dict, unc: dict | None, *, driveline: bool = True, drop=(),
                       extra95: float = 0.0) -> list | None:
    """``K_interval95`` of an efficiency variant ``value`` of ``point``: the main efficiency's terms scaled
    to it (each is relative), less those in ``drop`` (and the driveline's unless ``driveline``), with
    ``extra95`` (a correction's own 95 % half-width) in quadrature."""
    eta, terms = point.get("efficiency"), point.get("efficiency_u95_terms") or {}
    if not (isinstance(value, (int, float)) and math.isfinite(value)):
        return None
    basis = interval_basis(unc, point)
    skip = {"driveline", "engine_wear", *drop} | ({"air"} if basis["air_factors"] is not None else set())
    k = value / eta if isinstance(eta, (int, float)) and math.isfinite(eta) and eta else 1.0
    sym95 = math.sqrt(sum((k * v) ** 2 for n, v in terms.items() if n not in skip and isinstance(v, (int, float))
                          and math.isfinite(v)) + (extra95 or 0.0) ** 2)
    return interval95(value, sym95, basis["air_factors"], basis["driveline_max_frac"] if driveline else 0.0,
                      basis["wear_max_frac"])


def range_fault(name: str, value) -> dict | None:
    """The fault of an efficiency ``name`` outside 0…1 (it marks the point as the main efficiency's does)."""
    if isinstance(value, (int, float)) and math.isfinite(value) and not 0.0 <= value <= 1.0:
        return {"channel": name, "reason": f"{name} {value:.3f} outside 0..1: a calibration, map or correction "
                "does not fit this point"}
    return None


def calibration_rel_for(calibration_rel: float, point: dict, tare: dict | None) -> float:
    """The calibration term at this point: the slope's, and the tare's (the zero read at rest before GO
    carries its own standard uncertainty ``u_nm``, relative to this point's torque)."""
    torque = point.get("torque_secondary_nm", math.nan)
    u_nm = (tare or {}).get("u_nm", 0.0) or 0.0
    if not (isinstance(torque, float) and math.isfinite(torque) and abs(torque) > 0.0) or not u_nm:
        return calibration_rel
    return math.hypot(calibration_rel, u_nm / abs(torque))


def point_systematic(point: dict, calibration_rel: float, engine_map_rel: float, air_rel: float = 0.0,
                     air_factors=None, driveline_max_frac: float = 0.0, wear_max_frac: float = 0.0) -> dict:
    """The 95 % systematic half-widths of ``point``'s efficiency, its total ``efficiency_u95`` and its
    ``efficiency_interval95`` (``air_factors``, ``driveline_max_frac``, ``wear_max_frac``: :func:`interval_basis`).

    NaN (and no terms) without an efficiency.  ``air_rel`` 0 is a run from before the air was stated.
    """
    eff = point.get("efficiency", math.nan)
    if not isinstance(eff, float) or not math.isfinite(eff):
        return {"efficiency_sys95": math.nan, "efficiency_sys95_calibration": math.nan,
                "efficiency_sys95_engine_map": math.nan, "efficiency_sys95_air": math.nan,
                "efficiency_sys95_driveline": math.nan, "efficiency_u95": math.nan, "efficiency_u95_terms": None,
                "efficiency_interval95": None}
    cal, emap, air = 2.0 * eff * calibration_rel, 2.0 * eff * engine_map_rel, 2.0 * eff * (air_rel or 0.0)
    drive = eff * (1.0 / (1.0 - driveline_max_frac) - 1.0) if driveline_max_frac else 0.0
    wear = eff * (1.0 / (1.0 - wear_max_frac) - 1.0) if wear_max_frac else 0.0
    # any other symmetric term the point already states (e.g. a part-throttle curve's friction estimate)
    extra = {k[len("efficiency_sys95_"):]: v for k, v in point.items() if k in _EXTRA_SYS95
             and isinstance(v, float) and math.isfinite(v) and v > 0.0}
    sq_extra = sum(v * v for v in extra.values())
    ci = point.get("efficiency_ci95", math.nan)
    ci = ci if isinstance(ci, float) and math.isfinite(ci) else 0.0
    # the symmetric systematic terms (the air's is its factor's distribution instead when the day is unknown)
    sys_sym95 = math.sqrt(cal * cal + emap * emap + (0.0 if air_factors is not None else air * air) + sq_extra)
    sym95 = math.hypot(ci, sys_sym95)
    interval = interval95(eff, sym95, air_factors, driveline_max_frac, wear_max_frac)
    out = {"efficiency_sys95": half_width(interval95(eff, sys_sym95, air_factors, driveline_max_frac, wear_max_frac)),
           "efficiency_sys95_calibration": cal, "efficiency_sys95_engine_map": emap,
           "efficiency_sys95_air": air, "efficiency_sys95_driveline": drive, "efficiency_u95": half_width(interval),
           "efficiency_u95_terms": {"statistical": ci, "calibration": cal, "engine_map": emap, "air": air,
                                    "driveline": drive, **({"engine_wear": wear} if wear else {}), **extra},
           "efficiency_interval95": interval}
    # a variant the point already gives (the figure before the I·alpha correction): the same terms, scaled
    for key in VARIANTS_BEFORE_TERMS:
        v = point.get(key)
        if isinstance(v, (int, float)) and math.isfinite(v):
            out[f"{key}_interval95"] = interval95(v, sym95 * abs(v / eff) if eff else sym95, air_factors,
                                                  driveline_max_frac, wear_max_frac)
    return out


#: efficiency variants a point carries before its systematic terms are stated (dyno.analysis.inertia): each
#: gets ``<variant>_interval95`` here; the later ones (loss-, zero-corrected) from :func:`variant_interval95`
VARIANTS_BEFORE_TERMS = ("efficiency_uncorrected",)

#: symmetric 95 % terms a point may carry from its reduction, combined here when present
_EXTRA_SYS95 = ("efficiency_sys95_friction",)
