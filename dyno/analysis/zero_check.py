"""Torque-channel zero checks: the zero read at rest before GO and after the last point (pure).

A strain-gauge bridge's zero drifts (temperature, adhesive creep).  Read at rest -- the
shafts stopped, so the gauge carries no torque -- before the test and after it, the
zero's change over the test bounds the error every point's torque carries from it.
Beyond ``drift_max_nm`` the run is flagged; optionally the points get a linearly
drift-corrected torque and efficiency as *extra* keys (the raw points stay as measured,
so a replay still reproduces them exactly).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from dyno.analysis.efficiency import batch_mean
from dyno.protocol import v1


def zero_reading(codes, status, calibration, *, n_batches: int = 16) -> dict:
    """Mean torque (secondary N m, through the calibration) of a window at rest and its 95 % half-width.

    At rest the signal is the bridge's white noise (no firing or shaft ripple), so batches of a
    quarter second are already independent; 16 of them keep the interval itself steady.
    """
    codes = np.asarray(codes)
    status = np.asarray(status)
    good = codes[((status & v1.ADC_STATUS_ERR) == 0) & ~np.isin(codes, (0, 0xFFFF))].astype(float)
    if good.size < 2 * n_batches:
        return {"torque_nm": math.nan, "ci95_nm": math.nan, "n_adc": int(good.size)}
    mean, sem = batch_mean(good, n_batches)
    return {"torque_nm": float(calibration.torque_secondary_nm(mean)),
            "ci95_nm": float(stats.t.ppf(0.975, n_batches - 1) * sem / calibration.slope_counts_per_nm),
            "n_adc": int(good.size)}


def drift_check(before: dict, after: dict, drift_max_nm: float) -> dict:
    """The zero's change over the test, its 95 % half-width, and whether it is beyond the limit."""
    out = {"before": before, "after": after, "drift_max_nm": drift_max_nm, "drift_nm": math.nan,
           "drift_ci95_nm": math.nan, "flagged": False, "note": ""}
    if not (math.isfinite(before.get("torque_nm", math.nan)) and math.isfinite(after.get("torque_nm", math.nan))):
        out["note"] = "zero not read " + ("before GO" if not math.isfinite(before.get("torque_nm", math.nan))
                                          else "after the last point") + f": {before.get('why') or after.get('why')}"
        return out
    d = after["torque_nm"] - before["torque_nm"]
    out["drift_nm"] = d
    out["drift_ci95_nm"] = math.hypot(before["ci95_nm"], after["ci95_nm"])
    if abs(d) > drift_max_nm and abs(d) > out["drift_ci95_nm"]:  # beyond the limit, and not noise
        out["flagged"] = True
        out["note"] = (f"torque zero drifted {d:+.3f} N m over the test (limit {drift_max_nm:g} N m): every "
                       "point's torque carries up to that error")
    return out


def zero_at(check: dict, t_s: float) -> float:
    """The zero (N m) at host time ``t_s``, linear between the two readings' mid times."""
    b, a = check["before"], check["after"]
    tb, ta = b["t_mid_s"], a["t_mid_s"]
    if not ta > tb:
        return b["torque_nm"]
    return b["torque_nm"] + (a["torque_nm"] - b["torque_nm"]) * (t_s - tb) / (ta - tb)


def corrected_point_keys(point: dict, check: dict, unc: dict | None = None) -> dict:
    """Linearly drift-corrected torque and efficiency for one point (extra keys): the efficiency with every
    term of the point's (``unc``: :func:`~dyno.analysis.systematic.interval_basis`) in its
    ``efficiency_zero_corrected_interval95``, and outside 0…1 a fault naming it that marks the point."""
    from dyno.analysis.systematic import range_fault, variant_interval95

    t0, t1 = point.get("host_t_start_s"), point.get("host_t_end_s")
    torque, eff = point.get("torque_secondary_nm"), point.get("efficiency")
    if t0 is None or t1 is None or torque is None or not math.isfinite(check.get("drift_nm", math.nan)):
        return {}
    z = zero_at(check, 0.5 * (t0 + t1))
    tc = torque - z
    out = {"torque_secondary_zero_corrected_nm": tc}
    if eff is not None and math.isfinite(eff) and torque:
        ez = out["efficiency_zero_corrected"] = eff * tc / torque
        out["efficiency_zero_corrected_interval95"] = variant_interval95(ez, point, unc)
        fault = range_fault("efficiency_zero_corrected", ez)
        if fault is not None:
            out["faults"], out["valid"] = [*(point.get("faults") or ()), fault], False
    return out


def tare(calibration, zero: dict):
    """The calibration measured from the zero read at rest: ``(tared_entry, tare_record)``, or
    ``(calibration, None)`` when there is no finite zero.

    A strain-gauge bridge's offset moves between calibrations (the thesis rig's four intercepts
    scatter by ~60 counts, 0.6 N m); its slope moves far less.  Read at rest before GO, the offset is
    measured to ±0.1 N m, so the points take their zero from it: the intercept becomes the code at
    rest, :math:`b' = b + a\\,T_0`.  The record keeps what a replay needs (``zero_counts``) and the
    zero's own uncertainty (``u_nm``, standard), which stays in each point's calibration term.
    """
    import dataclasses

    z = zero.get("torque_nm", math.nan)
    if not isinstance(z, float) or not math.isfinite(z):
        return calibration, None
    zero_counts = calibration.intercept_counts + z * calibration.slope_counts_per_nm
    rec = {"zero_counts": float(zero_counts), "zero_nm": float(z), "u_nm": float(zero.get("ci95_nm", 0.0)) / 2.0,
           "intercept_counts_before": float(calibration.intercept_counts)}
    return dataclasses.replace(calibration, intercept_counts=float(zero_counts)), rec
