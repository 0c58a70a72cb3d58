"""Import a folder of the thesis rig's logs (Messick 2018, VT CVT dyno) into a dyno run directory.

Layout read (one file per channel per steady point N, no headers; see docs/legacy-import.md)::

    P_N.csv, S_N.csv   timestamp_us,rpm          primary / secondary Hall: the Arduino's latest
                                                 edge time and its rpm, polled at ~150 Hz, so rows
                                                 repeat until a new edge arrives
    ADC_N.csv          timestamp_us,adc_counts   AD7171 conversions (~127 Hz)
    TORQUE_N.csv       timestamp_us,torque_nm    the same samples converted by the thesis software
    cal_values.csv     slope,intercept,r2        calibration history (last row in force)
    engine_power_RPM.csv  rpm,hp                 engine map

The raw rows become the same events the live v0 reader produces (Hall
events carry the device rpm in ``code``), points are re-derived from them by
:func:`dyno.analysis.points.reduce_point` (so ``dyno replay`` reproduces
them), and every defect of the real data is reported per point and channel
as a fault instead of being averaged in silently.

Nothing is written until every input file has been parsed and checked: a
malformed file raises :class:`dyno.errors.ConfigError` naming the file and the
line, and leaves no run directory behind.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dyno.errors import ConfigError
from dyno.protocol import v1

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

FILE_RE = re.compile(r"^(P|S|ADC|TORQUE)_(\d+)\.csv$")
PREFIX_CHANNEL = {"P": "primary", "S": "secondary", "ADC": "adc", "TORQUE": "torque_file"}
CHANNEL_ID = {"primary": v1.CH_PRIMARY, "secondary": v1.CH_SECONDARY, "adc": v1.CH_ADC}
VALUE_NAME = {"P": "rpm", "S": "rpm", "ADC": "adc_counts", "TORQUE": "torque_nm"}

ERROR, WARNING = "error", "warning"


# --------------------------------------------------------------------------
# reading files


def read_legacy_csv(path: Path, prefix: str) -> tuple[list[int], list[float]]:
    """Rows ``timestamp_us,value`` of one legacy file; raises ConfigError naming the line.

    Timestamps are the Arduino's u32 ``micros()``; rpm and ADC values are the
    u16 slots of the legacy frame, TORQUE values are floats.
    """
    value_name = VALUE_NAME[prefix]
    expected = f"2 comma-separated fields timestamp_us,{value_name} (no header)"
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ConfigError(path, "file", "UTF-8 text") from None
    except OSError as exc:
        raise ConfigError(path, "file", f"a readable file ({exc.strerror})") from None
    ts, vals = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != 2:
            raise ConfigError(path, f"line {lineno}", f"{expected}, got {len(cells)} fields")
        try:
            t = int(cells[0])
        except ValueError:
            raise ConfigError(path, f"line {lineno}, field timestamp_us",
                              f"an integer microsecond count, got {cells[0].strip()!r}") from None
        if not 0 <= t <= U32_MAX:
            raise ConfigError(path, f"line {lineno}, field timestamp_us",
                              f"a u32 (0..{U32_MAX}), got {t}")
        cell = cells[1].strip()
        if prefix == "TORQUE":
            try:
                v = float(cell)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise ConfigError(path, f"line {lineno}, field {value_name}", f"a finite number, got {cell!r}")
        else:
            try:
                v = int(cell)
            except ValueError:
                raise ConfigError(path, f"line {lineno}, field {value_name}",
                                  f"an integer 0..{U16_MAX}, got {cell!r}") from None
            if not 0 <= v <= U16_MAX:
                raise ConfigError(path, f"line {lineno}, field {value_name}",
                                  f"an integer 0..{U16_MAX} (a u16 slot of the legacy frame), got {v}")
        ts.append(t)
        vals.append(v)
    return ts, vals


def scan_points(folder: Path) -> dict[int, dict[str, Path]]:
    """Point number -> {prefix: path} for every ``P|S|ADC|TORQUE_N.csv`` in ``folder``."""
    points: dict[int, dict[str, Path]] = {}
    for p in sorted(folder.iterdir()):
        m = FILE_RE.match(p.name)
        if m and p.is_file():
            points.setdefault(int(m.group(2)), {})[m.group(1)] = p
    return dict(sorted(points.items()))


def _find_shared(folder: Path, name: str, given: Path | None, option: str) -> Path:
    if given is not None:
        return Path(given)
    for cand in (folder / name, folder.parent / name):
        if cand.is_file():
            return cand
    raise ConfigError(folder, name, f"{name} in the run folder or its parent, or {option} FILE")


def load_calibration(path: Path):
    """(entry in force, row number or None, sha256) from a legacy cal_values.csv or a dyno history."""
    from dyno.analysis.calibration import latest, load_history, load_legacy_cal_values

    raw = _read_bytes(path, "a calibration file (cal_values.csv or a dyno calibration history)")
    first = next((ln for ln in raw.decode("utf-8-sig", "replace").splitlines() if ln.strip()), "")
    if first.strip().startswith("date"):
        history = load_history(path)
        return latest(history), None, hashlib.sha256(raw).hexdigest()
    history = load_legacy_cal_values(path)
    # The thesis software used the last row (latest() breaks the equal-date tie by file order).
    return latest(history), len(history), hashlib.sha256(raw).hexdigest()


def engine_map_for_run(path: Path) -> tuple[str, str]:
    """(text of engine_map.csv for the run dir, sha256 of the source); validates the source.

    The thesis's headerless ``rpm,hp`` rows are copied verbatim under a
    ``rpm,power_hp`` header so :func:`load_engine_map` reads the very numbers.
    """
    from dyno.analysis.engine_map import load_engine_map, load_legacy_engine_map

    raw = _read_bytes(path, "an engine map CSV")
    text = raw.decode("utf-8-sig", "replace")
    content = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    sha = hashlib.sha256(raw).hexdigest()
    if content and content[0].split(",")[0].strip() == "rpm":
        load_engine_map(path)  # validates; raises ConfigError naming file and line
        return f"# engine map copied from {path} (sha256 {sha})\n{text}", sha
    load_legacy_engine_map(path)
    rows = "".join(",".join(c.strip() for c in ln.split(",")) + "\n" for ln in content)
    head = (f"# imported from {path} (sha256 {sha}): the thesis rig's headerless rpm,hp engine map,\n"
            "# a used 10 hp Baja engine digitised from a published dyno chart (Messick 2018, Section 9.3)\n")
    return head + "rpm,power_hp\n" + rows, sha


def _read_bytes(path: Path, what: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError:
        raise ConfigError(path, "file", f"an existing, readable file: {what}") from None


# --------------------------------------------------------------------------
# rows -> events


@dataclass
class Channel:
    """One channel of one point after unwrapping and de-duplication."""

    name: str
    path: Path | None
    rows: int = 0
    t_us: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # kept, unwrapped, increasing
    values: np.ndarray = field(default_factory=lambda: np.zeros(0))
    repeats: int = 0  # rows repeating the previous timestamp (the poll saw no new event): expected
    conflicts: int = 0  # repeats of a timestamp with a different value
    backwards: int = 0  # rows whose timestamp went back: dropped
    backwards_max_us: int = 0


def _dedupe(name, path, t_unwrapped: list[int], values: list) -> Channel:
    ch = Channel(name, path, rows=len(t_unwrapped))
    keep_t, keep_v = [], []
    for t, v in zip(t_unwrapped, values):
        if keep_t and t == keep_t[-1]:
            ch.repeats += 1
            if v != keep_v[-1]:
                ch.conflicts += 1
            continue
        if keep_t and t < keep_t[-1]:
            # Seen in these logs: one ADC sample stamped twice, the copy ~60 us
            # earlier; an event stream must be monotonic, so the copy goes.
            ch.backwards += 1
            ch.backwards_max_us = max(ch.backwards_max_us, keep_t[-1] - t)
            continue
        keep_t.append(t)
        keep_v.append(v)
    ch.t_us = np.asarray(keep_t, dtype=np.int64)
    ch.values = np.asarray(keep_v, dtype=float)
    return ch


@dataclass
class LegacyPoint:
    number: int
    channels: dict[str, Channel]
    missing: list[str]
    t_start_us: int | None = None
    t_end_us: int | None = None
    clock_shift_us: int = 0


def _unwrap_points(raw: dict[int, dict[str, tuple[Path, list[int], list]]]) -> list[LegacyPoint]:
    """Unwrap every channel onto one timeline, point by point in file-number order.

    Each channel has its own :class:`Unwrapper` (channels interleave within a
    poll, so their rows are not jointly ordered).  A reference unwrapper
    follows the points' first rows, and a channel's first row is unwrapped
    relative to it, so a wrap between two channels' first rows is handled.
    A point that starts before the previous one ended means the Arduino
    restarted its clock; it is shifted after the previous point and reported.
    """
    from dyno.acquisition.reader import Unwrapper

    ref = Unwrapper()
    units = {name: Unwrapper() for name in PREFIX_CHANNEL.values()}
    shift_us = 0
    prev_end = None
    out = []
    for number, files in raw.items():
        first_raw = next((files[k][1][0] for k in PREFIX_CHANNEL if k in files and files[k][1]), None)
        if first_raw is not None:
            ref(first_raw)
        unwrapped, missing = {}, []
        for prefix, name in PREFIX_CHANNEL.items():
            if prefix not in files:
                missing.append(name)
                continue
            path, ts, vals = files[prefix]
            u = units[name]
            if u.raw is None and ref.raw is not None:
                u.raw, u.unwrapped = ref.raw, ref.unwrapped
            unwrapped[name] = (path, [u(t) for t in ts], vals)
        p = LegacyPoint(number, {}, missing)
        firsts = [min(ts) for _, ts, _ in unwrapped.values() if ts]
        if firsts and prev_end is not None and min(firsts) + shift_us <= prev_end:
            old = shift_us
            # The true pause across a restart is unknowable: continue one second later.
            shift_us = prev_end + 1_000_000 - min(firsts)
            p.clock_shift_us = shift_us - old
        for name, (path, ts, vals) in unwrapped.items():
            p.channels[name] = _dedupe(name, path, [t + shift_us for t in ts], vals)
        times = [c.t_us for n, c in p.channels.items() if n != "torque_file" and c.t_us.size]
        if times:
            p.t_start_us = int(min(t[0] for t in times))
            p.t_end_us = int(max(t[-1] for t in times))
            prev_end = p.t_end_us
        out.append(p)
    return out


# --------------------------------------------------------------------------
# fault detection (pure: arrays in, fault dicts out)


def _fault(channel: str, reason: str, severity: str = WARNING, **extra) -> dict:
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
    return _fault(name, f"too few samples: {n} {what} vs ~{expected:.0f} expected", sev,
                  kind="few_samples")


def hall_faults(ch: Channel, nominal_s: float, engine_map=None) -> list[dict]:
    """Faults of one Hall channel (device rpm per edge in ``values``)."""
    name, t, rpm = ch.name, ch.t_us, ch.values
    faults = []
    if ch.rows == 0:
        return [_fault(name, f"{ch.path.name} is empty", ERROR, kind="empty")]
    if t.size < 2:
        return [_fault(name, f"never changes: {t.size} distinct edge time(s) in {ch.rows} rows", ERROR,
                       kind="stuck")]
    f = _samples_fault(name, ch.rows, EXPECTED_POLL_HZ * nominal_s, "polled rows")
    if f:
        faults.append(f)
    at_top = int(np.sum(rpm == U16_MAX))
    if at_top:
        # reduce_point averages the device rpm, so an overflowed slot would be averaged in.
        faults.append(_fault(name, f"{at_top} edges at the {U16_MAX} rpm rail (overflowed period)", ERROR,
                             kind="rail"))
    zero = int(np.sum(rpm == 0))
    if zero:
        faults.append(_fault(name, f"{zero} edges report 0 rpm (left out of the device-rpm mean)",
                             kind="rail"))
    valid = rpm[(rpm > 0) & (rpm < U16_MAX)]
    if valid.size >= 10 and np.all(valid == valid[0]):
        faults.append(_fault(name, f"device rpm never changes ({valid[0]:.0f} rpm on {valid.size} edges)",
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
        faults.append(_fault(
            name, f"missed edges: edge-count rpm {by_count:.0f} vs device rpm {dev_mean:.0f} "
                  f"({(by_count / dev_mean - 1) * 100:+.2f} %), ~{missed} edge(s) fell between polls; "
                  "the device rpm is used", kind="missed_edges", missed_edges=missed))
    if short:
        faults.append(_fault(name, f"{short} edge period(s) shorter than the device's rpm implies "
                                   "(double trigger or a torn read)", kind="inconsistent_period"))
    if valid.size >= 10:
        spikes = _spikes(valid, 0.1 * float(np.median(valid)))
        if spikes.any():
            shift = abs(valid.mean() / valid[~spikes].mean() - 1)
            sev = ERROR if shift > SPIKE_FATAL_SHIFT else WARNING
            faults.append(_fault(name, f"{int(spikes.sum())} rpm spike(s) (up to {valid[spikes].max():.0f} rpm); "
                                       f"they move the mean by {shift * 100:.2f} %", sev, kind="spike"))
        tv = (t[1:][(rpm[1:] > 0) & (rpm[1:] < U16_MAX)] - t[0]) / 1e6
        vv = rpm[1:][(rpm[1:] > 0) & (rpm[1:] < U16_MAX)]
        mean = float(valid.mean())
        cv = float(valid.std()) / mean
        span_s = (t[-1] - t[0]) / 1e6
        drift = float(np.polyfit(tv, vv, 1)[0]) * span_s / mean if tv.size >= 3 and np.ptp(tv) > 0 else 0.0
        if cv > UNSTEADY_CV_WARN or abs(drift) > UNSTEADY_DRIFT_WARN:
            sev = ERROR if cv > UNSTEADY_CV_ERROR or abs(drift) > UNSTEADY_DRIFT_ERROR else WARNING
            faults.append(_fault(name, f"not steady: rpm {valid.min():.0f}..{valid.max():.0f}, scatter "
                                       f"{cv * 100:.1f} %, drift {drift * 100:+.1f} % over the point", sev,
                                 kind="unsteady"))
        if engine_map is not None and name == "primary":
            out = (valid < engine_map.rpm_min) | (valid > engine_map.rpm_max)
            if out.any() and engine_map.covers(mean):
                faults.append(_fault(name, f"{int(out.sum())} of {valid.size} edges at rpm outside the engine map "
                                           f"[{engine_map.rpm_min:g}, {engine_map.rpm_max:g}] (the mean is inside)",
                                     kind="outside_map"))
    faults += _timestamp_faults(ch)
    return faults


def adc_faults(ch: Channel, nominal_s: float, calibration, torque_file: Channel | None) -> list[dict]:
    name, t, codes = ch.name, ch.t_us, ch.values
    if ch.rows == 0:
        return [_fault(name, f"{ch.path.name} is empty", ERROR, kind="empty")]
    faults = []
    if codes.size >= 2 and np.all(codes == codes[0]):
        rail = " (a rail: the AD7171 is not converting or not wired)" if codes[0] in RAILS else ""
        thesis = ""
        if torque_file is not None and torque_file.values.size:
            thesis = f"; the thesis's {torque_file.path.name} turned it into {torque_file.values.mean():.1f} N·m"
        faults.append(_fault(name, f"never changes: all {codes.size} conversions are {codes[0]:.0f} counts"
                                   f"{rail}{thesis}", ERROR, kind="stuck"))
        rate_hz = (codes.size - 1) / max((t[-1] - t[0]) / 1e6, 1e-9)
        if rate_hz > 1.15 * EXPECTED_ADC_HZ:
            faults.append(_fault(name, f"timestamps arrive at {rate_hz:.0f} Hz, faster than the AD7171's "
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
            faults.append(_fault(
                name, f"{int(spikes.sum())} glitch conversion(s) ({', '.join(f'{c:.0f}' for c in good[spikes][:3])} "
                      f"counts vs median {np.median(good):.0f}); averaged in they move the torque by "
                      f"{torque_all - torque_clean:+.2f} N·m ({shift * 100:.1f} %)", sev, kind="spike"))
    if t.size >= 3:
        period = float(np.median(np.diff(t)))
        gaps = np.diff(t) / period
        missed = int(np.sum(np.where(gaps > 1.5, np.rint(gaps) - 1, 0)))
        if missed > 0.05 * codes.size:
            faults.append(_fault(name, f"~{missed} conversions missed between polls", kind="missed_samples"))
    faults += _timestamp_faults(ch)
    if torque_file is None:
        faults.append(_fault("torque_file", "TORQUE file missing: no cross-check with the thesis's torque",
                             kind="missing"))
    elif torque_file.t_us.size:
        if torque_file.t_us.size != t.size or np.any(torque_file.t_us != t):
            faults.append(_fault("torque_file", f"{torque_file.path.name} timestamps differ from the ADC file's",
                                 kind="mismatch"))
        else:
            diff = np.abs(calibration.torque_secondary_nm(codes) - torque_file.values)
            if diff.max() > 1e-3:
                faults.append(_fault("torque_file", f"{torque_file.path.name} differs from ADC via the calibration in "
                                                    f"force by up to {diff.max():.3f} N·m (another calibration?)",
                                     kind="mismatch"))
    return faults


def _timestamp_faults(ch: Channel) -> list[dict]:
    faults = []
    if ch.backwards:
        faults.append(_fault(ch.name, f"{ch.backwards} row(s) with a timestamp going back (by up to "
                                      f"{ch.backwards_max_us} us) dropped", kind="non_monotonic"))
    if ch.conflicts:
        faults.append(_fault(ch.name, f"{ch.conflicts} row(s) repeat a timestamp with a different value "
                                      "(the first value is kept)", kind="conflict"))
    return faults


def point_faults(p: LegacyPoint, nominal_s: float, calibration, engine_map) -> list[dict]:
    """Every importer-detected fault of one point (reduce_point adds its own)."""
    faults = []
    prefix_of = {v: k for k, v in PREFIX_CHANNEL.items()}
    for name in p.missing:
        if name == "torque_file":
            faults.append(_fault(name, f"TORQUE_{p.number}.csv missing: no cross-check", kind="missing"))
        else:
            faults.append(_fault(name, f"{prefix_of[name]}_{p.number}.csv missing", ERROR, kind="missing"))
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
        faults.append(_fault("all", f"short point: {duration_s:.2f} s of the run's usual {nominal_s:.2f} s", sev,
                             kind="short"))
    all_t = np.sort(np.concatenate([c.t_us for n, c in p.channels.items() if n != "torque_file"]))
    if all_t.size >= 2:
        gap_s = float(np.diff(all_t).max()) / 1e6
        if gap_s > STALL_GAP_S:
            faults.append(_fault("all", f"no new row on any channel for {gap_s:.2f} s (the logger stalled)",
                                 kind="gap"))
    if p.clock_shift_us:
        faults.append(_fault("all", "timestamps went back before this point (Arduino restarted?); placed 1 s "
                                    "after the previous point", kind="clock_restart"))
    return faults


# --------------------------------------------------------------------------
# the import


def default_out_dir(folder: Path, root: Path | None = None) -> Path:
    if root is None:
        from dyno.runlog.files import runs_root

        root = runs_root()  # $DYNO_RUNS_DIR, else runs/
    path = root / f"legacy-{folder.name}"
    n = 1
    while path.exists():
        n += 1
        path = root / f"legacy-{folder.name}-{n}"
    return path


def _events(points: list[LegacyPoint]) -> list[v1.Event]:
    """All points' events in one time-ordered stream (Hall: device rpm in ``code``, as V0Reader)."""
    ev = []
    for p in points:
        for name, ch_id in CHANNEL_ID.items():
            ch = p.channels.get(name)
            if ch is None:
                continue
            ev.extend(v1.Event(ch_id, int(t), int(v), 0) for t, v in zip(ch.t_us.tolist(), ch.values.tolist()))
    ev.sort(key=lambda e: (e.t_us, e.channel))
    return ev


_NULLED_BY_FATAL = ("efficiency", "efficiency_sem")


def import_legacy(folder, out_dir=None, *, calibration_path=None, engine_map_path=None,
                  discard=DISCARDED_DEFAULT) -> dict:
    """Turn one thesis run folder into a dyno run directory; returns the import summary.

    Returns ``{"run_dir", "source", "points", "faults", "summary", "calibration", "engine_map"}``
    where ``points`` are the point documents written (reduce_point statistics
    plus ``legacy_point``, ``discarded``, ``legacy_faults``) and ``faults`` the
    flat list of every fault with its ``point``.

    Raises
    ------
    ConfigError
        A missing or malformed input (naming file and line), or a non-empty
        ``out_dir``; nothing is written then.
    """
    from dyno.runlog.writer import RunWriter

    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(folder, "DIR", "a folder of the thesis rig's logs (P_N.csv, S_N.csv, ADC_N.csv)")
    cal_path = _find_shared(folder, "cal_values.csv", calibration_path, "--calibration")
    map_path = _find_shared(folder, "engine_power_RPM.csv", engine_map_path, "--engine-map")
    calibration, cal_row, cal_sha = load_calibration(cal_path)
    map_text, map_sha = engine_map_for_run(map_path)
    files = scan_points(folder)
    if not files:
        raise ConfigError(folder, "P_N.csv", "at least one steady point's files (P_N.csv, S_N.csv, ADC_N.csv)")
    # Parse everything before writing anything: a malformed file leaves no run behind.
    raw = {n: {prefix: (path, *read_legacy_csv(path, prefix)) for prefix, path in fs.items()}
           for n, fs in files.items()}
    out = Path(out_dir) if out_dir is not None else default_out_dir(folder)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(out, "--out", "an empty or new directory (refusing to overwrite a run)")

    points = _unwrap_points(raw)
    durations = [(p.t_end_us - p.t_start_us) / 1e6 for p in points if p.t_start_us is not None]
    # The run's own usual point length is the yardstick for "too short" / "too few samples".
    nominal_s = float(np.median(durations)) if durations else NOMINAL_POINT_S
    discard = set(int(d) for d in discard)
    meta = {
        "mode": "legacy-import",
        "protocol": "v0",
        "legacy_source": str(folder.resolve()),
        "legacy_format": "VT CVT dyno 2019: P_N/S_N/ADC_N/TORQUE_N.csv, cal_values.csv, engine_power_RPM.csv",
        "calibration_source": str(cal_path), "calibration_row": cal_row, "calibration_sha256": cal_sha,
        "engine_map_source": str(map_path), "engine_map_sha256": map_sha,
        "expected_poll_hz": EXPECTED_POLL_HZ, "expected_adc_hz": EXPECTED_ADC_HZ,
        "nominal_point_s": nominal_s, "discarded_points": sorted(discard),
    }
    writer = RunWriter(out, meta, calibration=calibration.to_dict(), engine_map_text=map_text)
    try:
        result = _write(writer, folder, points, nominal_s, discard, calibration)
    except BaseException as exc:
        writer.close("fail", f"import failed: {type(exc).__name__}: {exc}")
        raise
    return result


def _write(writer, folder: Path, points: list[LegacyPoint], nominal_s: float, discard: set, calibration) -> dict:
    from dyno.analysis.calibration import CalibrationEntry
    from dyno.analysis.engine_map import load_engine_map
    from dyno.analysis.points import reduce_point
    from dyno.runlog.reader import load_run

    events = _events(points)
    for i in range(0, len(events), 4096):
        writer.events(events[i:i + 4096])
    writer.doc("legacy_import", source=str(folder.resolve()), points=[p.number for p in points],
               files={str(p.number): {n: c.path.name for n, c in p.channels.items()} for p in points},
               events=len(events))
    # Reduce from what was written, with the run's own calibration and map, exactly as replay does.
    run = load_run(writer.run_dir)
    cal = CalibrationEntry.from_dict(run.calibration)
    engine_map = load_engine_map(run.engine_map_path)
    docs, flat = [], []
    for index, p in enumerate(points):
        legacy = point_faults(p, nominal_s, cal, engine_map)
        if p.t_start_us is None:
            legacy.append(_fault("all", "no timestamps in any file: no point", ERROR, kind="empty"))
            flat += [{"point": p.number, **f} for f in legacy]
            continue
        doc = reduce_point(run.streams, p.t_start_us, p.t_end_us, cal, engine_map, index=index)
        doc.update(legacy_point=p.number, discarded=p.number in discard, legacy_faults=legacy)
        thesis = p.channels.get("torque_file")
        doc["thesis_torque_nm"] = float(thesis.values.mean()) if thesis is not None and thesis.values.size else math.nan
        doc["legacy_channels"] = {n: {"rows": c.rows, "distinct": int(c.t_us.size), "repeats": c.repeats,
                                      "backwards_dropped": c.backwards, "conflicts": c.conflicts}
                                  for n, c in p.channels.items()}
        rp_faults = list(doc["faults"])
        fatal = [f for f in legacy if f["severity"] == ERROR]
        if fatal and not math.isnan(doc["efficiency"]):
            # reduce_point found a number the raw data cannot support: withhold it and say why.
            for k in _NULLED_BY_FATAL:
                doc[k] = math.nan
            doc["valid"] = False
            doc["faults"] = doc["faults"] + [{"channel": f["channel"], "reason": f["reason"], "severity": ERROR}
                                             for f in fatal]
            doc["withheld_by_import"] = True
        writer.doc("point", **doc)
        docs.append(doc)
        flat += [{"point": p.number, "severity": ERROR, "source": "reduce_point", **f} for f in rp_faults]
        flat += [{"point": p.number, "source": "import", **f} for f in legacy]
    summary = _summary(docs, flat, nominal_s)
    writer.doc("faults", faults=flat)
    writer.doc("summary", **summary)
    writer.close("success", f"imported {len(docs)} points from {folder.name}",
                 n_faults=len(flat), n_errors=summary["faults_by_severity"].get(ERROR, 0))
    return {"run_dir": str(writer.run_dir), "source": str(folder), "points": docs, "faults": flat,
            "summary": summary, "calibration": cal.to_dict(), "engine_map": str(engine_map.source)}


def _summary(docs, flat, nominal_s) -> dict:
    valid = [d["legacy_point"] for d in docs
             if d["valid"] and not d["discarded"] and not math.isnan(d["efficiency"])]
    by_sev: dict[str, int] = {}
    for f in flat:
        by_sev[f["severity"]] = by_sev.get(f["severity"], 0) + 1
    return {"n_points": len(docs), "valid_points": valid, "n_valid": len(valid),
            "discarded_points": [d["legacy_point"] for d in docs if d["discarded"]],
            "without_efficiency": [d["legacy_point"] for d in docs if math.isnan(d["efficiency"])],
            "faults_by_severity": by_sev, "nominal_point_s": nominal_s}
