r"""What cancels in a difference of two runs' efficiencies, and what is left: its 95 % uncertainty ``U_d``.

Pure (no I/O).  A run's efficiency carries, beside its scatter, three systematic terms shared by all its
points (:mod:`dyno.analysis.systematic`): the torque calibration, the engine map and the air.  In the
difference ``d = η_B − η_A`` of two runs at one secondary speed a term that is *common* to both runs
largely cancels; what it leaves is stated, term by term, as a 95 % half-width (coverage factor 2):

* **statistical**: never cancels (each run's noise is its own): ``1.96 · sqrt(s_A² + s_B²)``.
* **calibration**, the same entry (date and slope) in both runs: the slope's error is one factor on both
  efficiencies, ``(1+g) η``, so only ``|d| · u_slope`` is left — plus each run's own tare (the zero read at
  rest before GO), which is independent per run.  Different entries: both full terms in quadrature.
* **engine map**, the same map (sha256) — on one rig, so taken to be the same engine: its relative error
  ``e(n)`` is common where both runs run the engine at one speed.  The host's **assumption** (not a
  measurement): the map's relative error changes smoothly, by at most its standard deviation over
  :data:`MAP_DECORRELATION_RPM` of engine speed, so ``e(n_B) − e(n_A)`` has a standard uncertainty of
  ``u_map · √2 · min(1, |n_B − n_A| / 1000 rpm)`` (the √2: at 1000 rpm apart, two independent errors).
  Left: ``η · that`` and ``|d| · u_map`` (the common part on the difference itself).  Different maps:
  both full terms in quadrature.
* **air**: both runs corrected to their own air (a sensor or a given reading): what the readings are known
  to, each run's term, combined as independent (conservative: one sensor's bias would cancel).  Otherwise
  — either run uncorrected — the days may differ and nothing cancels: both full terms in quadrature (two
  uncorrected runs: the plausible-day term √2 over).

Runs that record no ``uncertainty`` (from before it was stated) give no systematic terms: each is
reported "unknown" and ``U_d`` is the statistical part alone.
"""

from __future__ import annotations

import math

import numpy as np

K95 = 2.0  # coverage factor of the systematic terms (as dyno.analysis.systematic)
#: The host's assumption on the engine map's error: it changes by at most its sd over this engine speed.
MAP_DECORRELATION_RPM = 1000.0
CANCELLED, RESIDUAL, NOT_CANCELLED, UNKNOWN = "cancelled", "residual", "not cancelled", "unknown"
TERMS = ("statistical", "calibration", "engine_map", "air")


def _f(x) -> float:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else math.nan


def run_systematics(run: dict) -> dict:
    """What one run says about its systematic terms (``run``: ``{"row", "meta"?}`` as :func:`compare` takes)."""
    from dyno.analysis.air import Ambient

    meta = run.get("meta") if isinstance(run.get("meta"), dict) else {}
    unc = meta.get("uncertainty") if isinstance(meta.get("uncertainty"), dict) else {}
    row = run.get("row") or {}
    amb = Ambient.from_dict(meta.get("ambient"))
    air_rel = _f(unc.get("air_rel"))
    if math.isnan(air_rel) and unc:
        air_rel = amb.air_rel_u()
    return {"calibration_rel": _f(unc.get("torque_calibration_rel")), "engine_map_rel": _f(unc.get("engine_map_rel")),
            "air_rel": air_rel, "ambient": amb, "has_ambient": isinstance(meta.get("ambient"), dict),
            "calibration": (row.get("calibration_date"), row.get("calibration_slope_counts_per_nm")),
            "engine_map_sha256": row.get("engine_map_sha256")}


def point_tare_rel(point: dict, calibration_rel: float) -> float:
    """The tare's relative part of a point's calibration term (``efficiency_sys95_calibration`` is
    ``2 η hypot(u_slope, u_tare)``, :func:`dyno.analysis.systematic.calibration_rel_for`)."""
    eff, cal95 = _f(point.get("efficiency")), _f(point.get("efficiency_sys95_calibration"))
    if math.isnan(cal95) or math.isnan(calibration_rel) or not eff:
        return 0.0
    return math.sqrt(max(0.0, (cal95 / (K95 * abs(eff))) ** 2 - calibration_rel ** 2))


def describe_air(amb, has_ambient: bool) -> str:
    if not has_ambient:
        return "records no air (from before dyno logged it)"
    if not amb.corrected:
        return "uncorrected (no air known: the map at the J1349 reference day)"
    rh = "RH not given" if amb.rh_pct is None else f"{amb.rh_pct:.0f} %RH"
    return (f"{amb.source} {amb.temp_c:.1f} °C, {amb.pressure_kpa:.1f} kPa, {rh} "
            f"(J1349 factor {amb.j1349_factor:.3f}: the map taken to that day)")


def calibration_term(val_a, val_b, tare_rel_a, tare_rel_b, sys_a: dict, sys_b: dict) -> dict:
    """The calibration term of ``d = val_b − val_a`` for any quantity proportional to the measured torque
    (efficiency, torque, output power): the slope common -> ``|d|·u_slope``; the tares are each run's own."""
    ea, eb = np.asarray(val_a, float), np.asarray(val_b, float)
    d = np.abs(eb - ea)
    ca, cb = sys_a["calibration_rel"], sys_b["calibration_rel"]
    ta, tb = ea * np.asarray(tare_rel_a, float), eb * np.asarray(tare_rel_b, float)
    if math.isnan(ca) or math.isnan(cb):
        return _unknown("calibration")
    if sys_a["calibration"] == sys_b["calibration"] and sys_a["calibration"][1] is not None:
        date, slope = sys_a["calibration"]
        return {
            "status": RESIDUAL, "u95": K95 * np.sqrt((d * max(ca, cb)) ** 2 + ta ** 2 + tb ** 2),
            "reason": (f"same calibration entry ({date}, slope {slope:.3f} counts/N·m): its slope error is one "
                       f"factor on both runs and cancels but for |Δ|·{100 * max(ca, cb):.2f} %; each run's "
                       "tare (zero before GO) is its own and does not cancel")}
    return {
        "status": NOT_CANCELLED, "u95": K95 * np.sqrt((ea * ca) ** 2 + ta ** 2 + (eb * cb) ** 2 + tb ** 2),
        "reason": (f"different calibration entries ({sys_a['calibration'][0]} / {sys_b['calibration'][0]})"
                   if sys_a["calibration"][1] is not None and sys_b["calibration"][1] is not None else
                   "a run records no calibration entry (it cannot be told to be the same)")
        + ": each run's full calibration term, in quadrature"}


def difference_terms(eff_a, eff_b, rpm_primary_a, rpm_primary_b, sem_d, tare_rel_a, tare_rel_b,
                     sys_a: dict, sys_b: dict) -> dict:
    """Per term ``{"status", "reason", "u95": array}`` and the combined ``"u95"`` of ``d = eff_b − eff_a``.

    Arrays on the common grid (NaN outside a run's range); ``sys_*`` from :func:`run_systematics`.
    """
    ea, eb = np.asarray(eff_a, float), np.asarray(eff_b, float)
    d = np.abs(eb - ea)
    eta = 0.5 * (np.abs(ea) + np.abs(eb))
    terms = {"statistical": {"status": NOT_CANCELLED, "u95": 1.959964 * np.asarray(sem_d, float),
                             "reason": "each run's own scatter (and interpolation), independent"}}

    terms["calibration"] = calibration_term(ea, eb, tare_rel_a, tare_rel_b, sys_a, sys_b)

    # engine map: common where the engine runs at one speed; the change over |Δn| by the assumption above
    ma, mb = sys_a["engine_map_rel"], sys_b["engine_map_rel"]
    dn = np.abs(np.asarray(rpm_primary_b, float) - np.asarray(rpm_primary_a, float))
    if math.isnan(ma) or math.isnan(mb):
        terms["engine_map"] = _unknown("engine map")
    elif sys_a["engine_map_sha256"] and sys_a["engine_map_sha256"] == sys_b["engine_map_sha256"]:
        u = max(ma, mb)
        shift = eta * u * math.sqrt(2.0) * np.minimum(1.0, dn / MAP_DECORRELATION_RPM)
        dn_max = float(np.nanmax(dn)) if np.isfinite(dn).any() else math.nan
        terms["engine_map"] = {
            "status": RESIDUAL, "u95": K95 * np.hypot(shift, d * u),
            "reason": (f"same engine map ({sys_a['engine_map_sha256'][:8]}) on one rig, taken to be one engine: "
                       f"its error cancels but for its change between the runs' engine speeds (up to "
                       f"{dn_max:.0f} rpm apart here) — assumed: the map's relative error changes by at most "
                       f"its sd ({100 * u:.1f} %) over {MAP_DECORRELATION_RPM:.0f} rpm — "
                       f"and |Δη|·{100 * u:.1f} %")}
    else:
        why = ("different engine maps" if sys_a["engine_map_sha256"] and sys_b["engine_map_sha256"]
               else "a run records no engine map sha256 (it cannot be told to be the same)")
        terms["engine_map"] = {"status": NOT_CANCELLED, "u95": K95 * np.hypot(ea * ma, eb * mb),
                               "reason": f"{why}: each run's full map term, in quadrature"}

    # air: corrected runs keep only their readings' tolerance; an uncorrected run's day is unknown
    aa, ab = sys_a["air_rel"], sys_b["air_rel"]
    corr_a, corr_b = sys_a["ambient"].corrected, sys_b["ambient"].corrected
    if math.isnan(aa) or math.isnan(ab):
        terms["air"] = _unknown("air")
    else:
        u95 = K95 * np.hypot(ea * aa, eb * ab)
        if corr_a and corr_b:
            terms["air"] = {"status": RESIDUAL, "u95": u95,
                            "reason": "both runs corrected to their own air (SAE J1349): only what each reading "
                                      "is known to remains, taken as independent"}
        elif corr_a or corr_b:
            terms["air"] = {"status": NOT_CANCELLED, "u95": u95,
                            "reason": f"only run {'A' if corr_a else 'B'} corrected: the other's day is unknown "
                                      "and does not cancel"}
        else:
            terms["air"] = {"status": NOT_CANCELLED, "u95": u95,
                            "reason": "neither run corrected: their days may differ (the uncorrected term of "
                                      "each, independent); give --ambient or fit a sensor"}
    total = np.sqrt(sum(np.nan_to_num(t["u95"]) ** 2 for t in terms.values()))
    total[~np.isfinite(ea) | ~np.isfinite(eb)] = np.nan
    return {"terms": terms, "u95": total}


def _unknown(what: str) -> dict:
    return {"status": UNKNOWN, "u95": np.array(0.0),
            "reason": f"a run records no {what} uncertainty (from before it was stated): not included"}
