"""Reduce a steady-state window of raw streams to one operating point.

The live controller and ``dyno replay`` call the same function on the same
raw events, so a replay reproduces the live points exactly (and re-processes
them with another calibration or engine map when asked).

Speeds are mean speeds by edge count over the window (insensitive to firing
ripple); their scatter is the standard deviation of per-period rpm, their
standard error comes from batch means; the torque's from the low end of its
spectrum (:mod:`dyno.analysis.spectral_sem`: white converter noise, many more
degrees of freedom).  ADC conversions with the AD7171 error bit, or at a rail
(0 / 65535), are excluded and counted, never averaged in.
"""

from __future__ import annotations

import math

import numpy as np

from dyno.acquisition.rpm import rpm_by_count, rpm_per_period
from dyno.analysis.efficiency import batch_mean, point_efficiency
from dyno.analysis.engine_map_range import NoThrottleCurve, OutOfMapRange
from dyno.analysis.part_throttle_air import friction_u95_nm
from dyno.analysis.spectral_sem import satterthwaite_dof, spectral_sem
from dyno.protocol import v1

ADC_RAILS = (0, 0xFFFF)


BATCH_S = 0.5  # batch length for standard errors: >> the firing-ripple correlation time (~40 ms)


def batch_count(t0_us: int, t1_us: int) -> int:
    """Batches of ~0.5 s: a 3 s point gets 6, a 24 s point 48.

    Few batches make the standard error itself uncertain (chi-squared with
    n-1 degrees of freedom), and a controller that measures *until* the error
    is small would then stop on lucky underestimates; more batches as the
    window grows keep that optional-stopping bias small.
    """
    return max(6, int((t1_us - t0_us) / 1e6 / BATCH_S))


def _speed(streams, channel: int, t0_us: int, t1_us: int) -> dict:
    edges = streams.edge_window(channel, t0_us, t1_us)
    rpm, periods = rpm_by_count(edges)
    _, per = rpm_per_period(edges)
    device_rpm = streams.edge_rpm_window(channel, t0_us, t1_us)
    out = {"rpm": rpm, "n_edges": int(edges.size), "std": float(per.std()) if per.size > 1 else math.nan,
           "sem": math.nan, "source": "edge_count"}
    nb = batch_count(t0_us, t1_us)
    if per.size >= 2 * nb:
        out["sem"] = batch_mean(per, nb)[1]
    if device_rpm.size and np.any(device_rpm > 0):
        # v0 logs: the device's own rpm per edge is the trustworthy period when
        # the 150 Hz poll missed edges; prefer it and keep the count as a check.
        valid = device_rpm[device_rpm > 0]
        out.update(rpm=float(valid.mean()), std=float(valid.std()), source="device_rpm",
                   rpm_by_count=rpm)
        out["sem"] = batch_mean(valid, nb)[1] if valid.size >= 2 * nb else math.nan
    return out


def reduce_point(streams, t0_us: int, t1_us: int, calibration, engine_map, *, index: int | None = None,
                 throttle_frac: float = 1.0) -> dict:
    """Statistics of one steady window ``[t0_us, t1_us]`` (host-unwrapped device times).

    Returns a flat dict with means, standard deviations, standard errors
    (``*_sem``), sample counts, the time span, powers and efficiency, and a
    ``faults`` list of what kept a value from being computed.

    ``throttle_frac`` is the throttle commanded over the window (recorded as the point's
    ``throttle_frac``): the efficiency's denominator is the engine map's curve at that throttle
    (:meth:`~dyno.analysis.engine_map.EngineMap.at_throttle`).  A map without one leaves the
    efficiency undefined (NaN, ``efficiency_reason`` naming the throttle) and the point otherwise
    valid: its torque, speeds, ratio and output power do not depend on the map.
    """
    faults = []
    p = _speed(streams, v1.CH_PRIMARY, t0_us, t1_us)
    s = _speed(streams, v1.CH_SECONDARY, t0_us, t1_us)
    t_adc, codes, status = streams.adc_window(t0_us, t1_us)
    err = (status & v1.ADC_STATUS_ERR) != 0
    rail = np.isin(codes, ADC_RAILS)
    good = codes[~err & ~rail]
    point = {
        "throttle_frac": float(throttle_frac),
        "t_start_us": int(t0_us), "t_end_us": int(t1_us), "duration_s": (t1_us - t0_us) / 1e6,
        "rpm_primary": p["rpm"], "rpm_primary_std": p["std"], "rpm_primary_sem": p["sem"],
        "n_primary_edges": p["n_edges"],
        "rpm_secondary": s["rpm"], "rpm_secondary_std": s["std"], "rpm_secondary_sem": s["sem"],
        "n_secondary_edges": s["n_edges"],
        "n_adc": int(codes.size), "n_adc_error": int(err.sum()), "n_adc_rail": int(rail.sum()),
        "adc_mean": math.nan, "adc_std": math.nan,
    }
    if index is not None:
        point["index"] = index
    for name, sp in (("primary", p), ("secondary", s)):
        if sp["n_edges"] < 2:
            faults.append({"channel": name, "reason": f"{sp['n_edges']} edges in the window: no speed"})
    if good.size >= 2:
        point["adc_mean"] = float(good.mean())
        point["adc_std"] = float(good.std())
        nb = batch_count(t0_us, t1_us)
        adc_sem = batch_mean(good, nb)[1] if good.size >= 2 * nb else float(good.std() / math.sqrt(good.size))
        adc_dof = nb - 1
        # the spectrum's low end: many more degrees of freedom than the batches (dyno.analysis.spectral_sem)
        spec_sem, spec_dof = spectral_sem(good, (t1_us - t0_us) / 1e6)
        if spec_dof:
            adc_sem, adc_dof = spec_sem, spec_dof
    else:
        adc_sem, adc_dof = math.nan, 0
        faults.append({"channel": "adc", "reason": f"{good.size} valid conversions in the window"})
    if point["n_adc_error"]:
        faults.append({"channel": "adc", "reason": f"{point['n_adc_error']} conversions with the AD7171 error bit excluded",
                       "severity": "warning"})
    if point["n_adc_rail"]:
        faults.append({"channel": "adc", "reason": f"{point['n_adc_rail']} conversions at a rail excluded",
                       "severity": "warning"})
    torque = calibration.torque_secondary_nm(point["adc_mean"]) if good.size >= 2 else math.nan
    point["torque_secondary_nm"] = float(torque)
    point["torque_secondary_std_nm"] = float(point["adc_std"] / calibration.slope_counts_per_nm)
    point["torque_secondary_sem_nm"] = float(adc_sem / calibration.slope_counts_per_nm)
    point["torque_secondary_sem_dof"] = int(adc_dof)
    rp, rs = point["rpm_primary"], point["rpm_secondary"]
    point["ratio"] = rp / rs if rs and rs > 0 and not math.isnan(rp) else math.nan
    point.update(power_out_w=math.nan, power_in_w=math.nan, efficiency=math.nan, efficiency_sem=math.nan,
                 efficiency_ci95=math.nan, efficiency_reason=None)
    if not any(math.isnan(x) for x in (rp, rs, torque)):
        point["power_out_w"] = torque * rs * 2 * math.pi / 60
        try:
            curve = engine_map.at_throttle(throttle_frac) if hasattr(engine_map, "at_throttle") else engine_map
            eff = point_efficiency(rp, _nz(p["sem"]), rs, _nz(s["sem"]), torque, _nz(point["torque_secondary_sem_nm"]),
                                   curve)
        except NoThrottleCurve as exc:
            # Not a fault of the measurement: only the denominator is missing (a warning keeps the point).
            point["efficiency_reason"] = str(exc)
            faults.append({"channel": "efficiency", "reason": str(exc), "severity": "warning"})
        except OutOfMapRange as exc:
            point["efficiency_reason"] = f"engine speed outside the engine map: {exc}"
            faults.append({"channel": "primary", "reason": f"engine speed outside the engine map: {exc}"})
        else:
            point.update(power_out_w=eff["power_out_w"], power_in_w=eff["power_in_w"],
                         efficiency=eff["efficiency"], efficiency_sem=eff["efficiency_sem"])
            fr95 = friction_u95_nm(curve, rp)  # a part-throttle curve at the day's air: its friction estimate's term
            if fr95 > 0:
                point["efficiency_sys95_friction"] = float(eff["efficiency"] * fr95 / curve.torque_nm(rp))
            # 95 % interval half-width: the standard errors are estimates (the torque's from its spectrum, the
            # speeds' from batch means), so Student's t on their combined degrees of freedom, not 1.96
            dof = efficiency_dof(point, eff["efficiency"], eff["efficiency_sem"], batch_count(t0_us, t1_us) - 1)
            point["efficiency_dof"] = dof
            point["efficiency_ci95"] = float(_t975(dof) * eff["efficiency_sem"])
    eff = point["efficiency"]
    if math.isfinite(eff) and not 0.0 <= eff <= 1.0:
        # No drive train makes power: a calibration or an engine map that does not fit this run.
        faults.append({"channel": "efficiency", "reason": f"efficiency {eff:.3f} outside 0..1: the torque "
                       "calibration or the engine map does not fit this run"})
    point["faults"] = faults
    point["valid"] = not any(f.get("severity", "error") == "error" for f in faults)
    # what the efficiency divides by: the map's input power (an input torque channel replaces it:
    # dyno.analysis.input_torque, which sets "input_torque")
    point["efficiency_source"] = "engine_map"
    return point


def efficiency_dof(point: dict, eff: float, eff_sem: float, batch_dof: int) -> int:
    """Degrees of freedom of the efficiency's standard error: its torque term (``eff / T * sem_T``, with the
    torque's own dof) and the rest (the speeds', from ``batch_dof`` batches), by Welch-Satterthwaite."""
    t, t_sem, t_dof = point["torque_secondary_nm"], point["torque_secondary_sem_nm"], point["torque_secondary_sem_dof"]
    v_t = (eff / t * t_sem) ** 2 if t and math.isfinite(t_sem) and t_dof else 0.0
    v_all = eff_sem ** 2
    dof = satterthwaite_dof([(min(v_t, v_all), t_dof), (max(0.0, v_all - v_t), batch_dof)])
    return int(dof) if math.isfinite(dof) and dof >= 1 else max(1, batch_dof)


def _t975(dof: int) -> float:
    from scipy.stats import t

    return float(t.ppf(0.975, max(1, dof)))


def _nz(x: float) -> float:
    return 0.0 if x is None or math.isnan(x) else float(x)
