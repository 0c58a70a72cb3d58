"""Engine map: torque vs speed at full (and optionally part) throttle, for the efficiency denominator.

The rig cannot measure engine power (thesis Section 9.3): efficiency divides
the measured secondary power by the power an engine map says the engine makes
at the measured primary (crank) speed.  This module loads such maps,
interpolates them with a monotone, shape-preserving PCHIP of torque vs rpm,
refuses to extrapolate, and converts between the SAE J1349 standard
conditions the map is assumed to be corrected to and the run's ambient air.

A map may also hold part-throttle curves (a ``throttle`` column, one curve per
throttle fraction; :meth:`EngineMap.at_throttle`): a point measured at part
throttle takes its denominator from the curve at its own throttle, never from
the full-throttle one, and never from a blend of two throttles (the governor
makes torque at a given speed steep in throttle).

A map states its own uncertainty: a comment line ``# stated_u_rel = 0.05 | basis`` gives the relative
standard uncertainty of its torque and why (:attr:`EngineMap.stated_u_rel`, ``stated_u_basis``); a map
that states none has ``stated_u_rel = None`` and the run takes ``rig.toml [uncertainty] engine_map_rel``
(:mod:`dyno.analysis.u95_terms`).  ``# measured_on_this_engine = yes | no`` says whether the map is a
measurement of the rig's own engine (:attr:`EngineMap.measured_on_this_engine`; None when not said): one
that is not takes at least the spread of real engines about maps (``u95_terms.UNMEASURED_MAP_U_REL``, 9.8 %).
The shipped representative maps say no and state 10 %; a map measured through the input torque channel
(:func:`dyno.analysis.measured_map.write_map`) says yes and states its measurement's.

Only :func:`load_engine_map` and :func:`load_legacy_engine_map` read files;
malformed files raise :class:`dyno.errors.ConfigError` naming file, line and
field.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
from scipy.interpolate import PchipInterpolator

from dyno.analysis.air import j1349_correction_factor
from dyno.analysis.engine_map_range import THROTTLE_TOL, NoThrottleCurve, OutOfMapRange
from dyno.errors import ConfigError

#: Mechanical (imperial) horsepower in W: 550 ft·lbf/s.  US engine dyno
#: charts (the thesis map, Baja SAE forum data) use this, not metric PS.
W_PER_HP = 745.6998715822702
RAD_PER_S_PER_RPM = 2.0 * math.pi / 60.0


_VALUE_COLUMNS = {"torque_nm": "torque", "power_hp": "hp", "power_kw": "kw"}


def _torque_from_power_w(rpm: np.ndarray, power_w: np.ndarray) -> np.ndarray:
    return power_w / (rpm * RAD_PER_S_PER_RPM)


class EngineMap:
    """Full-throttle engine torque vs crank speed, interpolated by PCHIP.

    Parameters
    ----------
    rpm : array_like
        Crank speeds, strictly increasing, > 0, at least 2 points.
    torque_nm : array_like
        Brake torque at each speed, N·m, finite and >= 0.
    source : str, optional
        Where the data came from (file path), recorded for run metadata.
    sha256 : str, optional
        Hex SHA-256 of the source file's bytes, recorded for run metadata.

    Attributes
    ----------
    rpm, torque_nm_knots : numpy.ndarray
        The knots (read-only copies).
    rpm_min, rpm_max : float
    source, sha256 : str or None
    j1349_factor : float
        Correction factor this map was divided by (1.0 = standard conditions).
    ambient : tuple of (temp_c, dry_pressure_kpa) or None

    Notes
    -----
    Torque (not power) is interpolated: PCHIP (Fritsch–Carlson) chooses
    knot slopes so the interpolant is monotone wherever the data are and has
    no overshoot beyond neighbouring knots, unlike a cubic spline which rings
    around the governor droop.  Power is derived,

    .. math:: P(n) = T(n)\\,\\omega, \\quad \\omega = 2\\pi n / 60,
              \\qquad \\frac{dP}{dn} = \\frac{2\\pi}{60}\\left(T + n\\frac{dT}{dn}\\right).
    """

    def __init__(self, rpm, torque_nm, *, source: str | None = None, sha256: str | None = None,
                 _j1349_factor: float = 1.0, _ambient=None, _standard_torque_nm=None):
        n = np.array(rpm, dtype=float)
        t = np.array(torque_nm, dtype=float)
        if n.ndim != 1 or t.shape != n.shape:
            raise ValueError(f"EngineMap: rpm and torque_nm must be 1-D of equal length, "
                             f"got shapes {n.shape} and {t.shape}")
        if len(n) < 2:
            raise ValueError("EngineMap: at least 2 points are needed")
        if not (np.all(np.isfinite(n)) and np.all(np.isfinite(t))):
            raise ValueError("EngineMap: rpm and torque_nm must be finite")
        if np.any(n <= 0):
            raise ValueError("EngineMap: rpm must be > 0")
        bad = np.nonzero(np.diff(n) <= 0)[0]
        if len(bad):
            raise ValueError(f"EngineMap: rpm must be strictly increasing (point {bad[0] + 1}: "
                             f"{n[bad[0] + 1]:g} after {n[bad[0]]:g})")
        if np.any(t < 0):
            raise ValueError("EngineMap: torque_nm must be >= 0")
        n.setflags(write=False)
        t.setflags(write=False)
        self.rpm = n
        self.torque_nm_knots = t
        self.rpm_min = float(n[0])
        self.rpm_max = float(n[-1])
        self.source = source
        self.sha256 = sha256
        self.j1349_factor = float(_j1349_factor)
        self.ambient = _ambient
        # The standard-condition torque, so at_ambient() never compounds corrections.
        self._standard_torque_nm = t if _standard_torque_nm is None else _standard_torque_nm
        self._pchip = PchipInterpolator(n, t, extrapolate=False)
        self._dpchip = self._pchip.derivative()
        self.throttle_frac = 1.0  # the throttle this curve is at
        self.stated_u_rel: float | None = None  # the file's '# stated_u_rel' (relative standard), None: not stated
        self.stated_u_basis = ""
        self.measured_on_this_engine: bool | None = None  # the file's '# measured_on_this_engine', None: not said
        self.part_throttle: dict[float, EngineMap] = {}  # (on the full-throttle map) throttle -> curve

    # -- throttle ------------------------------------------------------------

    @property
    def throttles(self) -> list[float]:
        """The throttle fractions this map has curves for, ascending (1.0 always)."""
        return sorted({*self.part_throttle, 1.0})

    def at_throttle(self, throttle_frac: float) -> "EngineMap":
        """The curve at ``throttle_frac`` (within :data:`THROTTLE_TOL`); :class:`NoThrottleCurve` if none.

        No interpolation across throttle: in a governed engine the torque at a given speed falls from
        the full curve to nothing across the governor's droop band (~150 rpm), so between two curves
        a blend can be off by most of the torque.  A part-throttle point needs a curve at its throttle.
        """
        u = float(throttle_frac)
        if math.isfinite(u) and abs(u - 1.0) <= THROTTLE_TOL:
            return self
        for t, curve in self.part_throttle.items():
            if math.isfinite(u) and abs(u - t) <= THROTTLE_TOL:
                return curve
        raise NoThrottleCurve(u, self.throttles, self.source or "")

    def __repr__(self) -> str:
        amb = "" if self.ambient is None else f", ambient={self.ambient}"
        return (f"EngineMap({len(self.rpm)} points, {self.rpm_min:g}-{self.rpm_max:g} rpm, "
                f"source={self.source!r}{amb})")

    # -- range -------------------------------------------------------------

    def covers(self, rpm) -> bool:
        """True if every value of ``rpm`` is finite and within [rpm_min, rpm_max]."""
        n = np.asarray(rpm, dtype=float)
        return bool(np.all(np.isfinite(n) & (n >= self.rpm_min) & (n <= self.rpm_max)))

    def _checked(self, rpm) -> np.ndarray:
        n = np.asarray(rpm, dtype=float)
        if not self.covers(n):
            outside = n[~(np.isfinite(n) & (n >= self.rpm_min) & (n <= self.rpm_max))]
            first = outside.flat[0] if outside.size else n
            raise OutOfMapRange(float(first), self.rpm_min, self.rpm_max, self.source or "")
        return n

    @staticmethod
    def _out(x: np.ndarray):
        return float(x) if x.ndim == 0 else x

    # -- evaluation ----------------------------------------------------------

    def _torque(self, n: np.ndarray) -> np.ndarray:
        t = np.asarray(self._pchip(n), dtype=float)
        # Return knot values exactly: the cubic evaluated at its own end point can
        # be 1e-16 instead of 0 at a governor cut-off knot, which would turn
        # "no power here" into an efficiency of 1e14.
        i = np.clip(np.searchsorted(self.rpm, n), 0, len(self.rpm) - 1)
        at_knot = self.rpm[i] == n
        return np.where(at_knot, self.torque_nm_knots[i], t)

    def torque_nm(self, rpm):
        """Engine torque at ``rpm``, N·m (raises :class:`OutOfMapRange` outside the map)."""
        n = self._checked(rpm)
        return self._out(self._torque(n))

    def power_w(self, rpm):
        """Engine power :math:`P = T(n)\\,2\\pi n/60` at ``rpm``, W."""
        n = self._checked(rpm)
        return self._out(self._torque(n) * n * RAD_PER_S_PER_RPM)

    def dpower_drpm(self, rpm):
        """Slope of power vs speed, W per rpm (for uncertainty propagation).

        .. math:: \\frac{dP}{dn} = \\frac{2\\pi}{60}\\left(T(n) + n\\,T'(n)\\right)
        """
        n = self._checked(rpm)
        return self._out(RAD_PER_S_PER_RPM * (self._torque(n) + n * np.asarray(self._dpchip(n))))

    # -- ambient correction ----------------------------------------------------

    def at_ambient(self, temp_c: float, dry_pressure_kpa: float) -> "EngineMap":
        """The engine at the run's air: standard power divided by the J1349 factor.

        The map is assumed to be corrected to SAE J1349 standard conditions
        (25 °C, 99 kPa dry air).  On a hot day or at altitude the engine
        makes less power than the map says; dividing by
        :func:`j1349_correction_factor` (> 1 in thinner air) gives the power
        actually delivered, which is the right efficiency denominator.

        Always computed from the standard-condition map, so calling it on a
        map that is already at some ambient does not compound corrections.
        Part-throttle curves: the fuelled torque scales, the friction does not
        (:mod:`dyno.analysis.part_throttle_air`, with its stated friction term).
        """
        cf = j1349_correction_factor(temp_c, dry_pressure_kpa)
        std = self._standard_torque_nm
        src = f"{self.source} at {temp_c:g} C, {dry_pressure_kpa:g} kPa dry (SAE J1349 CF {cf:.4f})"
        out = EngineMap(self.rpm, std / cf, source=src, sha256=self.sha256, _j1349_factor=cf,
                        _ambient=(float(temp_c), float(dry_pressure_kpa)),
                        _standard_torque_nm=std)
        out.throttle_frac = self.throttle_frac
        out.stated_u_rel, out.stated_u_basis = self.stated_u_rel, self.stated_u_basis
        out.measured_on_this_engine = self.measured_on_this_engine
        out.file_source = getattr(self, "file_source", None) or self.source  # the file, for code that reloads it
        out.part_throttle = {t: self._part_at_ambient(c, temp_c, dry_pressure_kpa, cf)
                             for t, c in self.part_throttle.items()}
        return out

    def _part_at_ambient(self, curve: "EngineMap", temp_c: float, dry_pressure_kpa: float, cf: float) -> "EngineMap":
        """A part-throttle ``curve`` of this (full-throttle) map at the day's air: friction not scaled."""
        from dyno.analysis.part_throttle_air import part_throttle_at_ambient

        n = curve.rpm
        full_std = PchipInterpolator(self.rpm, self._standard_torque_nm)(np.clip(n, self.rpm_min, self.rpm_max))
        day, fr95 = part_throttle_at_ambient(n, curve._standard_torque_nm, full_std, cf)
        src = f"{curve.source} at {temp_c:g} C, {dry_pressure_kpa:g} kPa dry (SAE J1349 CF {cf:.4f}, friction unscaled)"
        out = EngineMap(n, day, source=src, sha256=curve.sha256, _j1349_factor=cf,
                        _ambient=(float(temp_c), float(dry_pressure_kpa)),
                        _standard_torque_nm=curve._standard_torque_nm)
        out.throttle_frac = curve.throttle_frac
        out.file_source = getattr(curve, "file_source", None) or curve.source
        out.friction_u95_knots_nm = fr95  # (dyno.analysis.part_throttle_air.friction_u95_nm)
        return out

    def metadata(self) -> dict:
        """Provenance for run metadata: source, sha256, range, correction."""
        return {"source": self.source, "sha256": self.sha256, "rpm_min": self.rpm_min,
                "rpm_max": self.rpm_max, "j1349_factor": self.j1349_factor,
                "ambient_temp_c": None if self.ambient is None else self.ambient[0],
                "ambient_dry_pressure_kpa": None if self.ambient is None else self.ambient[1],
                "throttles": self.throttles, "stated_u_rel": self.stated_u_rel, "stated_u_basis": self.stated_u_basis,
                "measured_on_this_engine": self.measured_on_this_engine}


# ----------------------------------------------------------------------------
# loaders


def _read(path: Path) -> tuple[bytes, str]:
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(path, "file", "an existing engine map CSV") from None
    try:
        return raw, raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ConfigError(path, "file", "UTF-8 text") from None


def _number(path: Path, lineno: int, name: str, text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        x = math.nan
    if not math.isfinite(x):
        raise ConfigError(path, f"line {lineno}, field {name}", f"a finite number, got {text!r}")
    return x


def _parse_rows(path: Path, rows: list[tuple[int, str]], value_name: str):
    """Validate data rows; returns (rpm, value) arrays.  Names the offending line."""
    rpm, val = [], []
    for lineno, line in rows:
        cells = [c.strip() for c in line.split(",")]
        if len(cells) != 2:
            raise ConfigError(path, f"line {lineno}",
                              f"2 comma-separated numbers rpm,{value_name}, got {len(cells)} fields")
        n = _number(path, lineno, "rpm", cells[0])
        v = _number(path, lineno, value_name, cells[1])
        if n <= 0:
            raise ConfigError(path, f"line {lineno}, field rpm", f"rpm > 0, got {cells[0]!r}")
        if rpm and n <= rpm[-1]:
            raise ConfigError(path, f"line {lineno}, field rpm",
                              f"rpm strictly increasing, got {n:g} after {rpm[-1]:g}")
        if v < 0:
            raise ConfigError(path, f"line {lineno}, field {value_name}",
                              f"a value >= 0, got {cells[1]!r}")
        rpm.append(n)
        val.append(v)
    if len(rpm) < 2:
        raise ConfigError(path, "data rows", f"at least 2 rows rpm,{value_name}, got {len(rpm)}")
    return np.array(rpm), np.array(val)


def _content_lines(text: str) -> list[tuple[int, str]]:
    # '#' lines document provenance (e.g. "REPRESENTATIVE map, not a measurement").
    return [(i, line) for i, line in enumerate(text.splitlines(), start=1)
            if line.strip() and not line.lstrip().startswith("#")]


STATED_U_FIELD = "stated_u_rel"


def _stated_u(path: Path, text: str) -> tuple[float | None, str]:
    """The map's ``# stated_u_rel = REL | basis`` comment: (REL, basis), or (None, "") when it states none."""
    for lineno, line in enumerate(text.splitlines(), start=1):
        body = line.strip().lstrip("#").strip() if line.lstrip().startswith("#") else ""
        if not body.startswith(STATED_U_FIELD):
            continue
        key, eq, rest = body.partition("=")
        value, _, basis = rest.partition("|")
        try:
            u = float(value) if eq and key.strip() == STATED_U_FIELD else math.nan
        except ValueError:
            u = math.nan
        if not 0.0 < u < 1.0:  # (NaN fails too)
            raise ConfigError(path, f"line {lineno}, field {STATED_U_FIELD}",
                              f"'# {STATED_U_FIELD} = REL | basis' with 0 < REL < 1 (relative standard "
                              f"uncertainty of the torque), got {line.strip()!r}")
        return u, basis.strip()
    return None, ""


MEASURED_FIELD = "measured_on_this_engine"


def _measured(path: Path, text: str) -> bool | None:
    """The map's ``# measured_on_this_engine = yes | no`` comment, None when it says neither."""
    for lineno, line in enumerate(text.splitlines(), start=1):
        body = line.strip().lstrip("#").strip() if line.lstrip().startswith("#") else ""
        key, eq, value = body.partition("=")
        if key.strip() != MEASURED_FIELD or not eq:
            continue
        word = value.split("|")[0].strip().lower()
        if word not in ("yes", "no"):
            raise ConfigError(path, f"line {lineno}, field {MEASURED_FIELD}",
                              f"'# {MEASURED_FIELD} = yes' or '= no', got {line.strip()!r}")
        return word == "yes"
    return None


def _with_stated_u(m: EngineMap, stated: tuple[float | None, str], measured: bool | None = None) -> EngineMap:
    for c in (m, *m.part_throttle.values()):
        c.stated_u_rel, c.stated_u_basis = stated
        c.measured_on_this_engine = measured
    return m


def load_engine_map(path) -> EngineMap:
    """Load an engine map CSV with a header naming the units.

    Format: optional ``#`` comment lines, then a header ``rpm,torque_nm``,
    ``rpm,power_hp`` (mechanical hp, 745.7 W) or ``rpm,power_kw``, then one
    row per speed, strictly increasing rpm.  Power is converted to torque at
    the knots (:math:`T = P/\\omega`) and torque is interpolated.  The map is
    taken to be at SAE J1349 standard conditions (see
    :meth:`EngineMap.at_ambient`).

    ``# stated_u_rel = REL | basis`` (a comment line anywhere before the data) states the map's relative
    standard uncertainty of torque and its basis; without it :attr:`EngineMap.stated_u_rel` is None.
    ``# measured_on_this_engine = yes | no``: whether the map is a measurement of the rig's own engine.

    Part throttle: a header ``throttle,rpm,torque_nm`` (or ``power_hp`` /
    ``power_kw``) adds a first column, the throttle fraction (0 < throttle <= 1);
    each throttle's rows are one curve (contiguous, rpm strictly increasing, at
    least 2 rows), and a curve at throttle 1 (full) is required: it is the map
    every full-throttle point and every other reader (the simulator, the shift
    curve) uses.  A two-column file is a full-throttle map.

    For the thesis's headerless ``rpm,hp`` file use
    :func:`load_legacy_engine_map`; guessing units from numbers is how
    efficiencies of 130 % get published.

    Raises
    ------
    ConfigError
        Naming the file, line and field (or header) that is wrong.
    """
    path = Path(path)
    raw, text = _read(path)
    lines = _content_lines(text)
    expected_header = ("a header rpm,torque_nm or rpm,power_hp or rpm,power_kw "
                       "(part-throttle maps: throttle,rpm,torque_nm ...)")
    if not lines:
        raise ConfigError(path, "header", expected_header)
    lineno, header = lines[0]
    cols = [c.strip() for c in header.split(",")]
    throttle = len(cols) == 3 and cols[0] == "throttle"
    if throttle:
        cols = cols[1:]
    if len(cols) != 2 or cols[0] != "rpm" or cols[1] not in _VALUE_COLUMNS:
        hint = ""
        try:
            [float(c) for c in cols]
            hint = " (headerless rpm,hp files: use load_legacy_engine_map)"
        except ValueError:
            pass
        raise ConfigError(path, f"line {lineno} (header)", f"{expected_header}, got {header.strip()!r}{hint}")
    kind = _VALUE_COLUMNS[cols[1]]
    sha = hashlib.sha256(raw).hexdigest()

    def curve(rows) -> EngineMap:
        rpm, val = _parse_rows(path, rows, cols[1])
        if kind == "torque":
            torque = val
        elif kind == "hp":
            torque = _torque_from_power_w(rpm, val * W_PER_HP)
        else:
            torque = _torque_from_power_w(rpm, val * 1000.0)
        return EngineMap(rpm, torque, source=str(path), sha256=sha)

    stated, measured = _stated_u(path, text), _measured(path, text)
    if not throttle:
        return _with_stated_u(curve(lines[1:]), stated, measured)
    groups = _throttle_groups(path, lines[1:], cols[1])
    full = curve(groups.pop(1.0))
    for u, rows in groups.items():
        c = curve(rows)
        c.throttle_frac = u
        c.source = f"{path} (throttle {u:g})"
        full.part_throttle[u] = c
    return _with_stated_u(full, stated, measured)


def _throttle_groups(path: Path, rows: list[tuple[int, str]], value_name: str) -> dict[float, list]:
    """Split ``throttle,rpm,value`` rows into one ``rpm,value`` row list per throttle (checked)."""
    groups: dict[float, list] = {}
    last = None
    for lineno, line in rows:
        cell, _, rest = line.partition(",")
        u = _number(path, lineno, "throttle", cell.strip())
        if not 0.0 < u <= 1.0:
            raise ConfigError(path, f"line {lineno}, field throttle", f"a fraction 0 < throttle <= 1, got {cell.strip()!r}")
        if u != last and u in groups:
            raise ConfigError(path, f"line {lineno}, field throttle",
                              f"each throttle's rows together (throttle {u:g} appeared before line {lineno})")
        if u != last and any(abs(u - t) <= THROTTLE_TOL for t in groups):
            raise ConfigError(path, f"line {lineno}, field throttle",
                              f"throttles more than {THROTTLE_TOL:g} apart, got {u:g} beside "
                              f"{min(groups, key=lambda t: abs(u - t)):g}")
        groups.setdefault(u, []).append((lineno, rest))
        last = u
    if 1.0 not in groups:
        raise ConfigError(path, "throttle", f"a full-throttle curve (rows with throttle 1), got throttle "
                          f"{', '.join(f'{t:g}' for t in sorted(groups)) or 'none'}")
    for u, g in groups.items():
        if len(g) < 2:
            raise ConfigError(path, f"line {g[0][0]}, field throttle",
                              f"at least 2 rows rpm,{value_name} per throttle, got {len(g)} at throttle {u:g}")
    return groups


def load_legacy_engine_map(path) -> EngineMap:
    """Load the thesis's headerless ``rpm,hp`` engine map (``engine_power_RPM.csv``).

    Each row is crank rpm and power in mechanical hp, digitised from a
    published go-kart dyno chart of a used 10 hp Baja engine (thesis
    Section 9.3).  Read in place; validated like :func:`load_engine_map`.
    """
    path = Path(path)
    raw, text = _read(path)
    lines = _content_lines(text)
    rpm, hp = _parse_rows(path, lines, "hp")
    return EngineMap(rpm, _torque_from_power_w(rpm, hp * W_PER_HP), source=str(path),
                     sha256=hashlib.sha256(raw).hexdigest())
