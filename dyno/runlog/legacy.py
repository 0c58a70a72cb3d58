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
from dyno.runlog.legacy_faults import (
    EXPECTED_POLL_HZ, EXPECTED_ADC_HZ, NOMINAL_POINT_S, DISCARDED_DEFAULT, U32_MAX, U16_MAX, ERROR, point_faults, fault_record, PREFIX_CHANNEL)

FILE_RE = re.compile(r"^(P|S|ADC|TORQUE)_(\d+)\.csv$")
CHANNEL_ID = {"primary": v1.CH_PRIMARY, "secondary": v1.CH_SECONDARY, "adc": v1.CH_ADC}
VALUE_NAME = {"P": "rpm", "S": "rpm", "ADC": "adc_counts", "TORQUE": "torque_nm"}



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
    from dyno.analysis.calibration_history import latest, load_history, load_legacy_cal_values

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
# the import


def default_out_dir(folder: Path, root: Path | None = None) -> Path:
    if root is None:
        from dyno.runlog.files import runs_root

        root = runs_root()  # $DYNO_RUNS_DIR, else $DYNO_STATE_DIR/runs
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
    from dyno.analysis.calibration_history import CalibrationEntry
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
            legacy.append(fault_record("all", "no timestamps in any file: no point", ERROR, kind="empty"))
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
