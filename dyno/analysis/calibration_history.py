"""Torque-sensor calibration history: the entry, its validation, the history file (the fit maths
is in :mod:`dyno.analysis.calibration`).

A calibration maps ADC counts to torque (thesis eq 9.1)::

    counts = slope_counts_per_nm * T_nm + intercept_counts
    ADC    = 108.19 T + 35145                                      (eq 9.1)

``T`` is the **secondary** torque on the brake-side channel and the **crank** torque on the engine-side
input channel (issue 27; ``gear_ratio_brake_per_secondary`` 1.0 there: the loads hang on the cradle's own
arm).  Each channel keeps its own history in this format (``calibration/torque_calibration.csv``,
``calibration/input_torque_calibration.csv``).

Only :func:`load_history`, :func:`load_legacy_cal_values` and :func:`append_entry` touch files.
Malformed files raise :class:`dyno.errors.ConfigError` naming the file, the line and the field.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from datetime import date as _date
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from dyno.errors import ConfigError, DynoError
from dyno.fileio import write_atomic

#: Brake-rotor rpm per secondary rpm on the thesis rig (32-tooth secondary
#: sprocket, 61-tooth brake sprocket).  With a lossless reduction the secondary
#: torque is the brake-shaft torque times this ratio.
GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY = 32 / 61

#: Standard gravity, m/s^2 (the value that defines kgf).  A lab in Blacksburg
#: has g about 9.800; the 0.07 % difference is below the fit's uncertainty but
#: can be passed in when known.
G_STANDARD_M_PER_S2 = 9.80665

HISTORY_COLUMNS = (
    "date",
    "slope_counts_per_nm",
    "intercept_counts",
    "r2",
    "n_samples",
    "lever_arm_m",
    "gear_ratio_brake_per_secondary",
    "note",
)

#: Default acceptance threshold on R^2 of the calibration line (the thesis
#: rig achieved 0.9997; anything below 0.999 means a slipping rope, a bad
#: bridge or a load applied in the wrong place).
R2_MIN_DEFAULT = 0.999


class CalibrationRejected(DynoError, ValueError):
    """A calibration fit is not good enough to use; the message says why."""


class NoCalibration(ConfigError, LookupError):
    """A calibration history holds no entry (a ConfigError, so the CLI exits 2)."""

    def __init__(self, path="calibration history"):
        super().__init__(path, "rows", "at least one calibration entry; run a torque calibration first")


class _FieldError(Exception):
    """Internal: one field failed validation (caller adds file/line context)."""

    def __init__(self, field_name: str, expected: str):
        self.field_name = field_name
        self.expected = expected
        super().__init__(f"{field_name}: {expected}")


# --------------------------------------------------------------------------
# field validation shared by the dataclass, from_dict and the CSV loaders


def _parse_date(value: Any) -> str:
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, _date):
        return value.isoformat()
    text = str(value).strip()
    try:
        _date_key(text)
    except ValueError:
        raise _FieldError("date", f"an ISO 8601 date such as 2019-04-18, got {value!r}") from None
    return text


def _date_key(text: str) -> datetime:
    """Sortable key of an ISO date or date-time (aware times compared in UTC)."""
    try:
        d = _date.fromisoformat(text)
        return datetime(d.year, d.month, d.day)
    except ValueError:
        dt = datetime.fromisoformat(text)  # raises ValueError if not ISO
        if dt.tzinfo is not None:
            dt = dt.astimezone(timezone.utc).replace(tzinfo=None)
        return dt


def _parse_float(name: str, value: Any, *, positive: bool = False, lo: float | None = None,
                 hi: float | None = None) -> float:
    what = "a finite number"
    if positive:
        what += " > 0"
    if lo is not None and hi is not None:
        what = f"a number in [{lo}, {hi}]"
    if isinstance(value, bool):  # bool is an int subclass; True is not a slope
        raise _FieldError(name, f"{what}, got {value!r}")
    try:
        x = float(str(value).strip()) if isinstance(value, str) else float(value)
    except (TypeError, ValueError):
        raise _FieldError(name, f"{what}, got {value!r}") from None
    if not math.isfinite(x) or (positive and not x > 0) or (lo is not None and x < lo) or (
            hi is not None and x > hi):
        raise _FieldError(name, f"{what}, got {value!r}")
    return x


def _parse_count(name: str, value: Any) -> int:
    expected = f"an integer >= 0 (0 = unknown), got {value!r}"
    if isinstance(value, bool):
        raise _FieldError(name, expected)
    if isinstance(value, (int, np.integer)):
        n = int(value)
    else:
        text = str(value).strip()
        # int("5.0") fails on purpose: a fractional sample count is a typo.
        try:
            n = int(text)
        except ValueError:
            raise _FieldError(name, expected) from None
    if n < 0:
        raise _FieldError(name, expected)
    return n


def _parse_lever(value: Any) -> float | None:
    if value is None or (isinstance(value, str) and value.strip() == ""):
        return None
    return _parse_float("lever_arm_m", value, positive=True)


def _validated_fields(raw: Mapping[str, Any]) -> dict[str, Any]:
    """Check and convert every field of one history entry (raises _FieldError)."""
    note = raw.get("note", "")
    if note is None:
        note = ""
    if not isinstance(note, str):
        raise _FieldError("note", f"a string, got {note!r}")
    if "\n" in note or "\r" in note:
        # One row per calibration keeps the file greppable and line numbers meaningful.
        raise _FieldError("note", "a single line of text (no newline)")
    return {
        "date": _parse_date(raw["date"]),
        # Physical bounds of a 16-bit bridge ADC: a slope or offset outside them is a unit or
        # typing mistake, and a huge one would overflow the torque and efficiency downstream.
        "slope_counts_per_nm": _parse_float("slope_counts_per_nm", raw["slope_counts_per_nm"],
                                            lo=0.01, hi=1e5),
        "intercept_counts": _parse_float("intercept_counts", raw["intercept_counts"], lo=-65536.0, hi=131072.0),
        "r2": _parse_float("r2", raw["r2"], lo=0.0, hi=1.0),
        "n_samples": _parse_count("n_samples", raw["n_samples"]),
        "lever_arm_m": _parse_lever(raw.get("lever_arm_m")),
        "gear_ratio_brake_per_secondary": _parse_float(
            "gear_ratio_brake_per_secondary",
            raw.get("gear_ratio_brake_per_secondary", GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY),
            lo=0.01, hi=100.0),
        "note": note,
    }


# --------------------------------------------------------------------------
# the history entry


@dataclass(frozen=True)
class CalibrationEntry:
    """One accepted calibration of the torque channel.

    Attributes
    ----------
    date : str
        ISO 8601 date (or date-time) of the calibration.
    slope_counts_per_nm : float
        ADC counts per N·m of **secondary** torque, > 0.
    intercept_counts : float
        ADC counts at zero torque (bridge offset).
    r2 : float
        Coefficient of determination of the fit, in [0, 1].
    n_samples : int
        ADC samples behind the fit; 0 means unknown (imported history).
    lever_arm_m : float or None
        Rope radius on the brake rotor used for the loads; None if unknown.
    gear_ratio_brake_per_secondary : float
        Brake rpm per secondary rpm used to refer the loads to the secondary
        (32/61 on the thesis rig).
    note : str
        Free text, one line.

    Notes
    -----
    The conversion is the inverse of thesis eq 9.1,

    .. math:: T_s = (c - b) / a ,

    with slope :math:`a` and intercept :math:`b`.
    """

    date: str
    slope_counts_per_nm: float
    intercept_counts: float
    r2: float
    n_samples: int
    lever_arm_m: float | None = None
    gear_ratio_brake_per_secondary: float = GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY
    note: str = ""

    def __post_init__(self):
        # Validate here too so a bad entry can never be appended to the history.
        try:
            fields = _validated_fields(self.to_dict())
        except _FieldError as exc:
            raise ValueError(f"CalibrationEntry.{exc.field_name}: {exc.expected}") from None
        for name, value in fields.items():
            object.__setattr__(self, name, value)

    def torque_secondary_nm(self, counts):
        """Secondary-shaft torque from ADC counts, :math:`T_s = (c - b)/a`.

        Parameters
        ----------
        counts : float or array_like
            Raw ADC counts.

        Returns
        -------
        float or numpy.ndarray
            Torque on the CVT secondary in N·m (same shape as ``counts``).
        """
        c = np.asarray(counts, dtype=float)
        t = (c - self.intercept_counts) / self.slope_counts_per_nm
        return float(t) if t.ndim == 0 else t

    def counts(self, torque_secondary_nm):
        """ADC counts expected for a secondary torque, :math:`c = a T_s + b`."""
        t = np.asarray(torque_secondary_nm, dtype=float)
        c = self.slope_counts_per_nm * t + self.intercept_counts
        return float(c) if c.ndim == 0 else c

    def to_dict(self) -> dict[str, Any]:
        """Plain dict with the history column names as keys."""
        return {name: getattr(self, name) for name in HISTORY_COLUMNS}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "CalibrationEntry":
        """Build from a mapping with the history column names.

        Raises
        ------
        ValueError
            If a field is missing, extra or invalid (the message names it).
        """
        missing = [k for k in HISTORY_COLUMNS[:5] if k not in data]
        extra = [k for k in data if k not in HISTORY_COLUMNS]
        if missing or extra:
            raise ValueError(f"CalibrationEntry.from_dict: missing {missing}, unknown {extra}")
        return cls(**{k: data[k] for k in HISTORY_COLUMNS if k in data})


# --------------------------------------------------------------------------
# history file


def _history_row(entry: CalibrationEntry) -> list[str]:
    # repr() is the shortest string that round-trips the float exactly.
    return [
        entry.date,
        repr(entry.slope_counts_per_nm),
        repr(entry.intercept_counts),
        repr(entry.r2),
        str(entry.n_samples),
        "" if entry.lever_arm_m is None else repr(entry.lever_arm_m),
        repr(entry.gear_ratio_brake_per_secondary),
        entry.note,
    ]


def _parse_history_text(text: str, path: Path) -> list[CalibrationEntry]:
    lines = text.splitlines()
    if not lines or lines[0].strip().lstrip("\ufeff") == "":
        raise ConfigError(path, "line 1 (header)", "the header " + ",".join(HISTORY_COLUMNS))
    header = [h.strip() for h in next(csv.reader([lines[0].lstrip("\ufeff")]))]
    if tuple(header) != HISTORY_COLUMNS:
        raise ConfigError(path, "line 1 (header)",
                          f"exactly {','.join(HISTORY_COLUMNS)}, got {','.join(header)}")
    entries = []
    for lineno, line in enumerate(lines[1:], start=2):
        if line.strip() == "":
            continue  # tolerate blank lines (an editor's trailing newline)
        row = next(csv.reader([line]))
        if len(row) != len(HISTORY_COLUMNS):
            raise ConfigError(path, f"line {lineno}",
                              f"{len(HISTORY_COLUMNS)} comma-separated fields "
                              f"({','.join(HISTORY_COLUMNS)}), got {len(row)}")
        try:
            fields = _validated_fields(dict(zip(HISTORY_COLUMNS, row)))
        except _FieldError as exc:
            raise ConfigError(path, f"line {lineno}, field {exc.field_name}", exc.expected) from None
        entries.append(CalibrationEntry(**fields))
    return entries


def _read_text(path: Path, what: str, encoding: str) -> str:
    """The file's text, or a ConfigError naming it: missing, not UTF-8, unreadable (a directory, permissions)."""
    try:
        return path.read_bytes().decode(encoding)
    except FileNotFoundError:
        raise ConfigError(path, "file", f"an existing {what}") from None
    except UnicodeDecodeError:
        raise ConfigError(path, "file", "UTF-8 text") from None
    except OSError as exc:
        raise ConfigError(path, "file", f"a readable {what} ({exc.strerror or exc})") from None


def load_history(path) -> list[CalibrationEntry]:
    """Read a calibration history CSV (new format), validating every field.

    Parameters
    ----------
    path : str or os.PathLike
        CSV with header ``date,slope_counts_per_nm,intercept_counts,r2,
        n_samples,lever_arm_m,gear_ratio_brake_per_secondary,note``, one
        calibration per row, oldest first.

    Returns
    -------
    list of CalibrationEntry
        In file order (possibly empty if only the header is present).

    Raises
    ------
    ConfigError
        Missing/unreadable file, wrong header, or a row with a bad field
        (the message names the file, the line and the field).
    """
    path = Path(path)
    return _parse_history_text(_read_text(path, "calibration history CSV", "utf-8"), path)


def latest(history: Sequence[CalibrationEntry]) -> CalibrationEntry:
    """The calibration in force: latest date, ties broken by file order.

    Ties are common (several calibrations in one day, or imported history
    with a placeholder date); the later row wins, as on the thesis rig where
    the last row of ``cal_values.csv`` was used.

    Raises
    ------
    NoCalibration
        If ``history`` is empty.
    """
    if not history:
        raise NoCalibration()
    best = max(range(len(history)), key=lambda i: (_date_key(history[i].date), i))
    return history[best]


def append_entry(path, entry: CalibrationEntry) -> None:
    """Append one calibration to the history file atomically.

    The new file (old bytes unchanged + one row) is written to a temporary
    file in the same directory, flushed and fsync'ed, then moved over the old
    one with :func:`os.replace`, so a crash or power cut leaves either the
    old or the new file, never a truncated one.  A missing file is created
    with the header.

    Raises
    ------
    ConfigError
        If the existing file is malformed; it is then left untouched, because
        appending to a file we cannot read would hide the damage.

    Notes
    -----
    Not safe against two processes appending at the same instant (the later
    replace wins); calibrations are run by one operator at a time.
    """
    if not isinstance(entry, CalibrationEntry):
        raise TypeError(f"append_entry needs a CalibrationEntry, got {type(entry).__name__}")
    path = Path(path)
    if path.exists():
        old = path.read_bytes()
        try:
            _parse_history_text(old.decode("utf-8"), path)
        except UnicodeDecodeError:
            raise ConfigError(path, "file", "UTF-8 text") from None
        if old and not old.endswith(b"\n"):
            old += b"\n"
        mode = path.stat().st_mode & 0o777
    else:
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow(HISTORY_COLUMNS)
        old = buf.getvalue().encode("utf-8")
        mode = 0o644
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(_history_row(entry))
    new = old + buf.getvalue().encode("utf-8")

    write_atomic(path, new, mode)


def load_legacy_cal_values(path, *, date: str = "2019-04-18",
                           note: str = "thesis rig 2019 (imported); date unknown",
                           gear_ratio_brake_per_secondary: float = GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY,
                           ) -> list[CalibrationEntry]:
    """Read the thesis rig's headerless ``cal_values.csv`` in place.

    Each row is ``slope,intercept,r2`` (counts per N·m of secondary torque,
    counts, R^2); the last row was the one in force.  The legacy format has
    no date, sample count or rope radius: entries get ``date`` (default: the
    day of the archived runs), ``n_samples = 0`` (unknown) and
    ``lever_arm_m = None``.

    Raises
    ------
    ConfigError
        Naming the file, line and field of the first bad row.
    """
    path = Path(path)
    text = _read_text(path, "cal_values.csv", "utf-8-sig")
    names = ("slope_counts_per_nm", "intercept_counts", "r2")
    entries = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if line.strip() == "":
            continue
        row = [c.strip() for c in line.split(",")]
        if len(row) != 3:
            raise ConfigError(path, f"line {lineno}",
                              f"3 numbers slope,intercept,r2 (no header), got {len(row)} fields")
        raw = dict(zip(names, row), date=date, n_samples=0, lever_arm_m=None,
                   gear_ratio_brake_per_secondary=gear_ratio_brake_per_secondary, note=note)
        try:
            fields = _validated_fields(raw)
        except _FieldError as exc:
            raise ConfigError(path, f"line {lineno}, field {exc.field_name}", exc.expected) from None
        entries.append(CalibrationEntry(**fields))
    if not entries:
        raise ConfigError(path, "file", "at least one row slope,intercept,r2")
    return entries
