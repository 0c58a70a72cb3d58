"""Faults of the thesis rig's logs, per point and channel (pure: arrays in, fault dicts out).

What :mod:`dyno.runlog.legacy` reports instead of averaging a defect in silently: short or stalled channels,
edges missed between polls, glitches, unsteady points, timestamps out of order, ADC rails.  The thresholds
below are the import's documented ones (docs/legacy-import.md).
"""

from __future__ import annotations

import math

import numpy as np

# (``ch``: a :class:`dyno.runlog.legacy.Channel`, ``p``: a ``LegacyPoint``; not imported: the import
# depends on these checks, never the other way)

#: The thesis Pi polled the Arduino at ~150 Hz (450 rows per 3 s point in these logs).
EXPECTED_POLL_HZ = 150.0
#: AD7171 output rate measured in these logs: one conversion every ~7876 us.
EXPECTED_ADC_HZ = 127.0
#: The thesis averaged each steady point over 3 s; used when a run has no better estimate.
NOMINAL_POINT_S = 3.0
#: Fraction of the expected samples below which a channel is short (warning) or unusable (error).
FEW_SAMPLES_WARN = 0.8
FEW_SAMPLES_ERROR = 0.5
#: No new row on any channel for this long means the logger stalled (normal spacing is ~8 ms).
STALL_GAP_S = 0.1
#: A Hall period this many times the device's own period means an edge fell between polls.
MISSED_EDGE_RATIO = 1.5
#: A sample this many robust sigmas (1.4826 MAD) from the point's median is a glitch ...
SPIKE_SIGMAS = 10.0
#: ... and it is fatal when it moves the point's mean by more than this fraction.
SPIKE_FATAL_SHIFT = 0.01
#: Steadiness of the device rpm within a point: coefficient of variation and drift over the window.
UNSTEADY_CV_WARN, UNSTEADY_CV_ERROR = 0.03, 0.10
UNSTEADY_DRIFT_WARN, UNSTEADY_DRIFT_ERROR = 0.05, 0.20
#: Points the thesis team discarded (point 0 was taken before loading).
DISCARDED_DEFAULT = (0,)

U32_MAX = 0xFFFFFFFF
U16_MAX = 0xFFFF
RAILS = (0, U16_MAX)


ERROR, WARNING = "error", "warning"
#: the log files' prefixes and the channels they hold
PREFIX_CHANNEL = {"P": "primary", "S": "secondary", "ADC": "adc", "TORQUE": "torque_file"}


# --------------------------------------------------------------------------
# fault detection (pure: arrays in, fault dicts out)


def fault_record(channel: str, reason: str, severity: str = WARNING, **extra) -> dict:
    return {"channel": channel, "reason": reason, "severity": severity, **extra}


def _robust_sigma(x: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def _spikes(x: np.ndarray, floor: float) -> np.ndarray:
    """Mask of isolated glitches: far from the median in robust sigmas and by more than ``floor``."""
    if x.size < 10:
        return np.zeros(x.size, bool)
    med = np.median(x)
    dev = np.abs(x - med)
    return (dev > SPIKE_SIGMAS * _robust_sigma(x)) & (dev > floor)


def _samples_fault(name: str, n: int, expected: float, what: str) -> dict | None:
    if expected <= 0 or n >= FEW_SAMPLES_WARN * expected:
        return None
    sev = ERROR if n < FEW_SAMPLES_ERROR * expected else WARNING
    return fault_record(name, f"too few samples: {n} {what} vs ~{expected:.0f} expected", sev,
                  kind="few_samples")


def hall_faults(ch, nominal_s: float, engine_map=None) -> list[dict]:
    """Faults of one Hall channel (device rpm per edge in ``values``)."""
    name, t, rpm = ch.name, ch.t_us, ch.values
    faults = []
    if ch.rows == 0:
        return [fault_record(name, f"{ch.path.name} is empty", ERROR, kind="empty")]
    if t.size < 2:
        return [fault_record(name, f"never changes: {t.size} distinct edge time(s) in {ch.rows} rows", ERROR,
                       kind="stuck")]
    f = _samples_fault(name, ch.rows, EXPECTED_POLL_HZ * nominal_s, "polled rows")
    if f:
        faults.append(f)
    at_top = int(np.sum(rpm == U16_MAX))
    if at_top:
        # reduce_point averages the device rpm, so an overflowed slot would be averaged in.
        faults.append(fault_record(name, f"{at_top} edges at the {U16_MAX} rpm rail (overflowed period)", ERROR,
                             kind="rail"))
    zero = int(np.sum(rpm == 0))
    if zero:
        faults.append(fault_record(name, f"{zero} edges report 0 rpm (left out of the device-rpm mean)",
                             kind="rail"))
    valid = rpm[(rpm > 0) & (rpm < U16_MAX)]
    if valid.size >= 10 and np.all(valid == valid[0]):
        faults.append(fault_record(name, f"device rpm never changes ({valid[0]:.0f} rpm on {valid.size} edges)",
                             ERROR, kind="stuck"))
        return faults
    # Each row's rpm is the device's own period ending at that edge (60e6/period,
    # checked on these logs), so a gap of k device periods means k-1 edges
    # fell between two 150 Hz polls.
    dt = np.diff(t).astype(float)
    dev_period = np.where(rpm[1:] > 0, 60e6 / np.maximum(rpm[1:], 1), np.nan)
    ratio = dt / dev_period
    missed = int(np.nansum(np.where(ratio > MISSED_EDGE_RATIO, np.rint(ratio) - 1, 0)))
    short = int(np.nansum(ratio < 1 / MISSED_EDGE_RATIO))
    if missed:
        by_count = 60e6 * (t.size - 1) / float(t[-1] - t[0])
        dev_mean = float(valid.mean()) if valid.size else math.nan
        faults.append(fault_record(
            name, f"missed edges: edge-count rpm {by_count:.0f} vs device rpm {dev_mean:.0f} "
                  f"({(by_count / dev_mean - 1) * 100:+.2f} %), ~{missed} edge(s) fell between polls; "
                  "the device rpm is used", kind="missed_edges", missed_edges=missed))
    if short:
        faults.append(fault_record(name, f"{short} edge period(s) shorter than the device's rpm implies "
                                   "(double trigger or a torn read)", kind="inconsistent_period"))
    if valid.size >= 10:
        spikes = _spikes(valid, 0.1 * float(np.median(valid)))
        if spikes.any():
            shift = abs(valid.mean() / valid[~spikes].mean() - 1)
            sev = ERROR if shift > SPIKE_FATAL_SHIFT else WARNING
            faults.append(fault_record(name, f"{int(spikes.sum())} rpm spike(s) (up to {valid[spikes].max():.0f} rpm); "
                                       f"they move the mean by {shift * 100:.2f} %", sev, kind="spike"))
        tv = (t[1:][(rpm[1:] > 0) & (rpm[1:] < U16_MAX)] - t[0]) / 1e6
        vv = rpm[1:][(rpm[1:] > 0) & (rpm[1:] < U16_MAX)]
        mean = float(valid.mean())
        cv = float(valid.std()) / mean
        span_s = (t[-1] - t[0]) / 1e6
        drift = float(np.polyfit(tv, vv, 1)[0]) * span_s / mean if tv.size >= 3 and np.ptp(tv) > 0 else 0.0
        if cv > UNSTEADY_CV_WARN or abs(drift) > UNSTEADY_DRIFT_WARN:
            sev = ERROR if cv > UNSTEADY_CV_ERROR or abs(drift) > UNSTEADY_DRIFT_ERROR else WARNING
            faults.append(fault_record(name, f"not steady: rpm {valid.min():.0f}..{valid.max():.0f}, scatter "
                                       f"{cv * 100:.1f} %, drift {drift * 100:+.1f} % over the point", sev,
                                 kind="unsteady"))
        if engine_map is not None and name == "primary":
            out = (valid < engine_map.rpm_min) | (valid > engine_map.rpm_max)
            if out.any() and engine_map.covers(mean):
                faults.append(fault_record(name, f"{int(out.sum())} of {valid.size} edges at rpm outside the engine map "
                                           f"[{engine_map.rpm_min:g}, {engine_map.rpm_max:g}] (the mean is inside)",
                                     kind="outside_map"))
    faults += _timestamp_faults(ch)
    return faults


def adc_faults(ch, nominal_s: float, calibration, torque_file) -> list[dict]:
    name, t, codes = ch.name, ch.t_us, ch.values
    if ch.rows == 0:
        return [fault_record(name, f"{ch.path.name} is empty", ERROR, kind="empty")]
    faults = []
    if codes.size >= 2 and np.all(codes == codes[0]):
        rail = " (a rail: the AD7171 is not converting or not wired)" if codes[0] in RAILS else ""
        thesis = ""
        if torque_file is not None and torque_file.values.size:
            thesis = f"; the thesis's {torque_file.path.name} turned it into {torque_file.values.mean():.1f} N·m"
        faults.append(fault_record(name, f"never changes: all {codes.size} conversions are {codes[0]:.0f} counts"
                                   f"{rail}{thesis}", ERROR, kind="stuck"))
        rate_hz = (codes.size - 1) / max((t[-1] - t[0]) / 1e6, 1e-9)
        if rate_hz > 1.15 * EXPECTED_ADC_HZ:
            faults.append(fault_record(name, f"timestamps arrive at {rate_hz:.0f} Hz, faster than the AD7171's "
                                       f"~{EXPECTED_ADC_HZ:.0f} Hz: stamped by the poll, not by a conversion",
                                 kind="rate"))
        return faults + _timestamp_faults(ch)
    f = _samples_fault(name, int(codes.size), EXPECTED_ADC_HZ * nominal_s, "distinct conversions")
    if f:
        faults.append(f)
    good = codes[~np.isin(codes, RAILS)]
    if good.size >= 10:
        spikes = _spikes(good, 500.0)
        if spikes.any():
            torque_all = calibration.torque_secondary_nm(good.mean())
            torque_clean = calibration.torque_secondary_nm(good[~spikes].mean())
            shift = abs(torque_all - torque_clean) / max(abs(torque_clean), 1e-9)
            sev = ERROR if shift > SPIKE_FATAL_SHIFT else WARNING
            faults.append(fault_record(
                name, f"{int(spikes.sum())} glitch conversion(s) ({', '.join(f'{c:.0f}' for c in good[spikes][:3])} "
                      f"counts vs median {np.median(good):.0f}); averaged in they move the torque by "
                      f"{torque_all - torque_clean:+.2f} N·m ({shift * 100:.1f} %)", sev, kind="spike"))
    if t.size >= 3:
        period = float(np.median(np.diff(t)))
        gaps = np.diff(t) / period
        missed = int(np.sum(np.where(gaps > 1.5, np.rint(gaps) - 1, 0)))
        if missed > 0.05 * codes.size:
            faults.append(fault_record(name, f"~{missed} conversions missed between polls", kind="missed_samples"))
    faults += _timestamp_faults(ch)
    if torque_file is None:
        faults.append(fault_record("torque_file", "TORQUE file missing: no cross-check with the thesis's torque",
                             kind="missing"))
    elif torque_file.t_us.size:
        if torque_file.t_us.size != t.size or np.any(torque_file.t_us != t):
            faults.append(fault_record("torque_file", f"{torque_file.path.name} timestamps differ from the ADC file's",
                                 kind="mismatch"))
        else:
            diff = np.abs(calibration.torque_secondary_nm(codes) - torque_file.values)
            if diff.max() > 1e-3:
                faults.append(fault_record("torque_file", f"{torque_file.path.name} differs from ADC via the calibration in "
                                                    f"force by up to {diff.max():.3f} N·m (another calibration?)",
                                     kind="mismatch"))
    return faults


def _timestamp_faults(ch) -> list[dict]:
    faults = []
    if ch.backwards:
        faults.append(fault_record(ch.name, f"{ch.backwards} row(s) with a timestamp going back (by up to "
                                      f"{ch.backwards_max_us} us) dropped", kind="non_monotonic"))
    if ch.conflicts:
        faults.append(fault_record(ch.name, f"{ch.conflicts} row(s) repeat a timestamp with a different value "
                                      "(the first value is kept)", kind="conflict"))
    return faults


def point_faults(p, nominal_s: float, calibration, engine_map) -> list[dict]:
    """Every importer-detected fault of one point (reduce_point adds its own)."""
    faults = []
    prefix_of = {v: k for k, v in PREFIX_CHANNEL.items()}
    for name in p.missing:
        if name == "torque_file":
            faults.append(fault_record(name, f"TORQUE_{p.number}.csv missing: no cross-check", kind="missing"))
        else:
            faults.append(fault_record(name, f"{prefix_of[name]}_{p.number}.csv missing", ERROR, kind="missing"))
    for name in ("primary", "secondary"):
        if name in p.channels:
            faults += hall_faults(p.channels[name], nominal_s, engine_map)
    if "adc" in p.channels:
        faults += adc_faults(p.channels["adc"], nominal_s, calibration, p.channels.get("torque_file"))
    if p.t_start_us is None:
        return faults
    duration_s = (p.t_end_us - p.t_start_us) / 1e6
    if duration_s < FEW_SAMPLES_WARN * nominal_s:
        sev = ERROR if duration_s < FEW_SAMPLES_ERROR * nominal_s else WARNING
        faults.append(fault_record("all", f"short point: {duration_s:.2f} s of the run's usual {nominal_s:.2f} s", sev,
                             kind="short"))
    all_t = np.sort(np.concatenate([c.t_us for n, c in p.channels.items() if n != "torque_file"]))
    if all_t.size >= 2:
        gap_s = float(np.diff(all_t).max()) / 1e6
        if gap_s > STALL_GAP_S:
            faults.append(fault_record("all", f"no new row on any channel for {gap_s:.2f} s (the logger stalled)",
                                 kind="gap"))
    if p.clock_shift_us:
        faults.append(fault_record("all", "timestamps went back before this point (Arduino restarted?); placed 1 s "
                                    "after the previous point", kind="clock_restart"))
    return faults


