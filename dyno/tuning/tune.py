"""CVT tune: the adjustable hardware of a mechanically controlled CVT.

A tune is a small TOML file (see ``docs/tuning.md`` and
``calibration/tunes/cvtech-stock.toml``) holding the primary flyweights and
spring, the secondary spring(s) and helix, the helix torque-split regression
coefficients and the fixed drive geometry the actuators need (sheave angle,
belt pitch length, centre distance, primary radius range).  Every quantity is
SI and its unit is part of its key (``mass_each_kg``, ``rate_n_per_m``...).

The dataclasses here are plain immutable values; :func:`tune_from_dict`
validates a parsed mapping and :func:`load_tune` is the only function that
touches a file.  Bad input raises :class:`dyno.errors.ConfigError` naming the
file, the dotted field and what was expected.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from dyno.errors import ConfigError

SCHEMA = "dyno.tune/1"


@dataclass(frozen=True)
class Drive:
    """Fixed drive geometry the actuators depend on.

    Attributes
    ----------
    sheave_half_angle_deg : float
        Groove half-angle (Sorge's alpha, Messick's beta).  Axial travel of
        the moving sheave ``dz`` and belt pitch-radius change ``dr`` are tied
        by ``dz = 2 tan(alpha) dr`` (Sorge eq. 20a).
    belt_pitch_length_m, centre_distance_m : float
        Open-belt geometry that ties the secondary radius to the primary one.
    primary_radius_min_m : float
        Primary pitch radius with the moving sheave at zero travel (low ratio,
        the belt just clamped).  Sheave travel is measured from here.
    primary_radius_max_m : float
        Primary pitch radius at full shift (sheave stop).
    gearbox_ratio : float
        Reduction after the secondary (secondary rpm / wheel rpm); only used to
        convert road loads.
    """

    sheave_half_angle_deg: float
    belt_pitch_length_m: float
    centre_distance_m: float
    primary_radius_min_m: float
    primary_radius_max_m: float
    gearbox_ratio: float = 1.0


@dataclass(frozen=True)
class FlyweightProfile:
    """Thesis sliding-mass flyweights (Messick 2018 eq. 9.2).

    ``radius_m`` is the flyweight centre-of-mass radius tabulated against the
    primary moving-sheave travel ``sheave_travel_m`` (strictly increasing,
    starting at 0).  A linear ramp is the two-point table.
    """

    count: int
    mass_each_kg: float
    sheave_travel_m: tuple[float, ...]
    radius_m: tuple[float, ...]
    #: of ``mass_each_kg``, tuning washers added to the weight's body (a weighed, known mass; the body is
    #: the same physical part with or without them)
    washer_mass_each_kg: float = 0.0

    @property
    def body_mass_each_kg(self) -> float:
        return self.mass_each_kg - self.washer_mass_each_kg


@dataclass(frozen=True)
class RollerTrack:
    """Roller-on-track centrifugal actuator (Sorge & Cammalleri eqs. 20-21).

    Rollers of total mass ``total_mass_kg`` are squeezed between a straight
    fixed ramp of slope ``fixed_ramp_angle_deg`` (beta_f, from the shaft axis:
    the roller centre moves ``dz_c = dr_c cot(beta_f)``) and a circular track
    on the sliding half-pulley (centre at radius ``track_centre_radius_m`` and
    axial offset ``track_centre_axial_m`` from the roller, radius
    ``track_radius_m`` to the roller centre).  ``roller_radius_min_m`` is the
    roller-centre radius at zero sheave travel.
    """

    total_mass_kg: float
    roller_radius_min_m: float
    track_centre_radius_m: float
    track_centre_axial_m: float
    track_radius_m: float
    fixed_ramp_angle_deg: float


@dataclass(frozen=True)
class PrimarySpring:
    """Primary compression spring: ``F = preload_n + rate_n_per_m * travel``."""

    preload_n: float
    rate_n_per_m: float


@dataclass(frozen=True)
class SecondarySpring:
    """Secondary spring, compression and/or torsion.

    Axial: ``F = preload_n + rate_n_per_m * travel`` (Sorge eq. 22, F_z0 + K s).
    Torsion: ``M = torsion_preload_nm + torsion_rate_nm_per_rad * twist`` where
    the twist grows with sheave travel through the helix.
    """

    preload_n: float
    rate_n_per_m: float
    torsion_preload_nm: float = 0.0
    torsion_rate_nm_per_rad: float = 0.0


@dataclass(frozen=True)
class Helix:
    """Secondary helix (torque-sensing cam).

    ``angle_from_axis_deg`` is Sorge's delta: a torque ``M`` on the track
    gives an axial force ``M tan(delta) / radius_m`` (eq. 22 with d = 2r).
    Helix catalogues often quote the lead angle from the plane of rotation,
    which is ``90 - delta``; the TOML key ``angle_reference`` says which.
    """

    angle_from_axis_deg: float
    radius_m: float


@dataclass(frozen=True)
class TorqueSplit:
    """Coefficients of Sorge & Cammalleri eq. 11 (published values default).

    ``friction_coefficient`` is the belt/driven-sheave f of the same equation.
    """

    a_opening: float = -0.9
    b_opening: float = 0.04
    a_closing: float = 1.85
    b_closing: float = 0.03
    friction_coefficient: float = 0.4


@dataclass(frozen=True)
class Tune:
    """One complete tune.  ``primary_actuator`` is ``"sliding_mass"`` or
    ``"roller_track"``; exactly the matching field is set."""

    name: str
    drive: Drive
    primary_spring: PrimarySpring
    secondary_spring: SecondarySpring
    helix: Helix
    primary_actuator: str = "sliding_mass"
    flyweights: FlyweightProfile | None = None
    roller_track: RollerTrack | None = None
    torque_split: TorqueSplit = field(default_factory=TorqueSplit)
    notes: str = ""

    def with_changes(self, **changes: Any) -> "Tune":
        """Return a copy with dotted-path changes, e.g.
        ``tune.with_changes(**{"primary_spring.rate_n_per_m": 2e4})``.
        Used by the sensitivity sweeps."""
        out = self
        for dotted, value in changes.items():
            out = _replace_dotted(out, dotted.split("."), value)
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping in the TOML layout (for storing with a run)."""
        return _tune_to_dict(self)


def _replace_dotted(obj: Any, parts: list[str], value: Any) -> Any:
    if len(parts) == 1:
        return replace(obj, **{parts[0]: value})
    child = getattr(obj, parts[0])
    return replace(obj, **{parts[0]: _replace_dotted(child, parts[1:], value)})


# ----------------------------------------------------------------- loading


class _Reader:
    """Pulls typed, range-checked values out of a nested mapping and turns
    every problem into a ConfigError naming the dotted field."""

    def __init__(self, path: str):
        self.path = path

    def err(self, fld: str, expected: str) -> ConfigError:
        return ConfigError(self.path, fld, expected)

    def table(self, data: Mapping, key: str, prefix: str, required: bool = True):
        fld = f"{prefix}{key}"
        if key not in data:
            if required:
                raise self.err(fld, "missing table")
            return None
        val = data[key]
        if not isinstance(val, Mapping):
            raise self.err(fld, "a table")
        return val

    def number(self, data: Mapping, key: str, prefix: str, *, lo: float | None = None,
               hi: float | None = None, lo_open: bool = False, default: float | None = None) -> float:
        fld = f"{prefix}{key}"
        if key not in data:
            if default is not None:
                return float(default)
            raise self.err(fld, "missing number")
        val = data[key]
        if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
            raise self.err(fld, f"a finite number, got {val!r}")
        val = float(val)
        if lo is not None and (val < lo or (lo_open and val == lo)):
            raise self.err(fld, f"{'>' if lo_open else '>='} {lo}, got {val}")
        if hi is not None and val > hi:
            raise self.err(fld, f"<= {hi}, got {val}")
        return val

    def integer(self, data: Mapping, key: str, prefix: str, lo: int = 1) -> int:
        fld = f"{prefix}{key}"
        val = data.get(key)
        if isinstance(val, bool) or not isinstance(val, int) or val < lo:
            raise self.err(fld, f"an integer >= {lo}, got {val!r}")
        return val

    def array(self, data: Mapping, key: str, prefix: str) -> tuple[float, ...]:
        fld = f"{prefix}{key}"
        val = data.get(key)
        if not isinstance(val, list) or len(val) < 2:
            raise self.err(fld, "an array of at least 2 numbers")
        out = []
        for v in val:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise self.err(fld, f"finite numbers only, got {v!r}")
            out.append(float(v))
        return tuple(out)

    def no_extra(self, data: Mapping, allowed: set[str], prefix: str) -> None:
        # Unknown keys are errors: a typo such as ``mass_each_g`` must not be
        # silently ignored and leave the default in force.
        for key in data:
            if key not in allowed:
                raise self.err(f"{prefix}{key}", f"unknown key (allowed: {', '.join(sorted(allowed))})")


def tune_from_dict(data: Mapping[str, Any], path: str | Path = "<tune>") -> Tune:
    """Validate a parsed tune mapping and build a :class:`Tune`.

    Raises
    ------
    ConfigError
        For a missing, mistyped, out-of-range or unknown field.
    """
    rd = _Reader(str(path))
    rd.no_extra(data, {"schema", "name", "notes", "drive", "primary", "secondary"}, "")
    schema = data.get("schema", SCHEMA)
    if schema != SCHEMA:
        raise rd.err("schema", f"{SCHEMA!r}, got {schema!r}")
    name = data.get("name", Path(str(path)).stem)
    if not isinstance(name, str) or not name:
        raise rd.err("name", "a non-empty string")
    notes = data.get("notes", "")
    if not isinstance(notes, str):
        raise rd.err("notes", "a string")

    d = rd.table(data, "drive", "")
    rd.no_extra(d, {"sheave_half_angle_deg", "belt_pitch_length_m", "centre_distance_m",
                    "primary_radius_min_m", "primary_radius_max_m", "gearbox_ratio"}, "drive.")
    drive = Drive(
        sheave_half_angle_deg=rd.number(d, "sheave_half_angle_deg", "drive.", lo=1.0, hi=45.0),
        belt_pitch_length_m=rd.number(d, "belt_pitch_length_m", "drive.", lo=0.0, lo_open=True),
        centre_distance_m=rd.number(d, "centre_distance_m", "drive.", lo=0.0, lo_open=True),
        primary_radius_min_m=rd.number(d, "primary_radius_min_m", "drive.", lo=0.0, lo_open=True),
        primary_radius_max_m=rd.number(d, "primary_radius_max_m", "drive.", lo=0.0, lo_open=True),
        gearbox_ratio=rd.number(d, "gearbox_ratio", "drive.", lo=0.0, lo_open=True, default=1.0),
    )
    if drive.primary_radius_max_m <= drive.primary_radius_min_m:
        raise rd.err("drive.primary_radius_max_m", "greater than drive.primary_radius_min_m")
    # The belt must be able to wrap both pulleys: L > 2C + pi*(r_min) roughly.
    if drive.belt_pitch_length_m <= 2.0 * drive.centre_distance_m + 2.0 * math.pi * drive.primary_radius_min_m:
        raise rd.err("drive.belt_pitch_length_m", "long enough to wrap both pulleys at the given centre distance")

    p = rd.table(data, "primary", "")
    rd.no_extra(p, {"actuator", "flyweights", "roller_track", "spring"}, "primary.")
    actuator = p.get("actuator", "sliding_mass")
    if actuator not in ("sliding_mass", "roller_track"):
        raise rd.err("primary.actuator", f"'sliding_mass' or 'roller_track', got {actuator!r}")
    tan_a = math.tan(math.radians(drive.sheave_half_angle_deg))
    travel_full_m = 2.0 * tan_a * (drive.primary_radius_max_m - drive.primary_radius_min_m)

    flyweights = roller = None
    if actuator == "sliding_mass":
        f = rd.table(p, "flyweights", "primary.")
        pre = "primary.flyweights."
        rd.no_extra(f, {"count", "mass_each_kg", "washer_mass_each_kg", "sheave_travel_m", "radius_m",
                        "ramp_radius_start_m", "ramp_radial_per_axial"}, pre)
        count = rd.integer(f, "count", pre)
        mass = rd.number(f, "mass_each_kg", pre, lo=0.0, lo_open=True, hi=5.0)
        washers = rd.number(f, "washer_mass_each_kg", pre, lo=0.0, default=0.0)
        if washers >= mass:
            raise rd.err(pre + "washer_mass_each_kg", f"less than mass_each_kg ({mass:g} kg), got {washers:g}")
        if "sheave_travel_m" in f or "radius_m" in f:
            travel = rd.array(f, "sheave_travel_m", pre)
            radius = rd.array(f, "radius_m", pre)
            if len(travel) != len(radius):
                raise rd.err(pre + "radius_m", "same length as sheave_travel_m")
            if travel[0] != 0.0 or any(b <= a for a, b in zip(travel, travel[1:])):
                raise rd.err(pre + "sheave_travel_m", "strictly increasing, starting at 0")
            if travel[-1] < travel_full_m * (1 - 1e-6):
                raise rd.err(pre + "sheave_travel_m",
                             f"covering the full sheave travel {travel_full_m:.5f} m")
            if min(radius) <= 0:
                raise rd.err(pre + "radius_m", "positive radii")
        else:
            # Linear ramp shorthand -> two-point profile over the full travel.
            r0 = rd.number(f, "ramp_radius_start_m", pre, lo=0.0, lo_open=True)
            ma = rd.number(f, "ramp_radial_per_axial", pre, lo=0.0, lo_open=True)
            travel = (0.0, travel_full_m)
            radius = (r0, r0 + ma * travel_full_m)
        flyweights = FlyweightProfile(count, mass, travel, radius, washers)
    else:
        rt = rd.table(p, "roller_track", "primary.")
        pre = "primary.roller_track."
        rd.no_extra(rt, {"total_mass_kg", "roller_radius_min_m", "track_centre_radius_m",
                         "track_centre_axial_m", "track_radius_m", "fixed_ramp_angle_deg"}, pre)
        roller = RollerTrack(
            total_mass_kg=rd.number(rt, "total_mass_kg", pre, lo=0.0, lo_open=True),
            roller_radius_min_m=rd.number(rt, "roller_radius_min_m", pre, lo=0.0, lo_open=True),
            track_centre_radius_m=rd.number(rt, "track_centre_radius_m", pre),
            track_centre_axial_m=rd.number(rt, "track_centre_axial_m", pre),
            track_radius_m=rd.number(rt, "track_radius_m", pre, lo=0.0, lo_open=True),
            fixed_ramp_angle_deg=rd.number(rt, "fixed_ramp_angle_deg", pre, lo=1.0, hi=89.0),
        )
        # The track circle must pass through the roller at zero travel, else
        # eq. 20b has no root there.
        lhs = (roller.roller_radius_min_m - roller.track_centre_radius_m) ** 2 + roller.track_centre_axial_m ** 2
        if abs(math.sqrt(lhs) - roller.track_radius_m) > 1e-4:
            raise rd.err(pre + "track_radius_m",
                         f"equal to the distance from track centre to roller at zero travel "
                         f"({math.sqrt(lhs):.5f} m) within 0.1 mm")

    s = rd.table(p, "spring", "primary.")
    pre = "primary.spring."
    rd.no_extra(s, {"rate_n_per_m", "preload_n", "force_at_full_shift_n"}, pre)
    rate = rd.number(s, "rate_n_per_m", pre, lo=0.0)
    if ("preload_n" in s) == ("force_at_full_shift_n" in s):
        raise rd.err(pre + "preload_n", "exactly one of preload_n or force_at_full_shift_n")
    if "preload_n" in s:
        preload = rd.number(s, "preload_n", pre, lo=0.0)
    else:
        # Messick eq. 9.3 states the spring by its full-shift force.
        preload = rd.number(s, "force_at_full_shift_n", pre, lo=0.0) - rate * travel_full_m
        if preload < 0:
            raise rd.err(pre + "force_at_full_shift_n", "large enough that the preload is not negative")
    primary_spring = PrimarySpring(preload, rate)

    sec = rd.table(data, "secondary", "")
    rd.no_extra(sec, {"spring", "helix", "torque_split"}, "secondary.")
    ss = rd.table(sec, "spring", "secondary.")
    pre = "secondary.spring."
    rd.no_extra(ss, {"preload_n", "rate_n_per_m", "torsion_preload_nm", "torsion_rate_nm_per_rad"}, pre)
    secondary_spring = SecondarySpring(
        preload_n=rd.number(ss, "preload_n", pre, lo=0.0),
        rate_n_per_m=rd.number(ss, "rate_n_per_m", pre, lo=0.0),
        torsion_preload_nm=rd.number(ss, "torsion_preload_nm", pre, lo=0.0, default=0.0),
        torsion_rate_nm_per_rad=rd.number(ss, "torsion_rate_nm_per_rad", pre, lo=0.0, default=0.0),
    )
    h = rd.table(sec, "helix", "secondary.")
    pre = "secondary.helix."
    rd.no_extra(h, {"angle_deg", "angle_reference", "radius_m"}, pre)
    angle = rd.number(h, "angle_deg", pre, lo=0.0, hi=89.0, lo_open=True)
    ref = h.get("angle_reference", "axis")
    if ref not in ("axis", "rotation_plane"):
        raise rd.err(pre + "angle_reference", f"'axis' or 'rotation_plane', got {ref!r}")
    helix = Helix(angle if ref == "axis" else 90.0 - angle,
                  rd.number(h, "radius_m", pre, lo=0.0, lo_open=True))
    ts = rd.table(sec, "torque_split", "secondary.", required=False) or {}
    pre = "secondary.torque_split."
    rd.no_extra(ts, {"a_opening", "b_opening", "a_closing", "b_closing", "friction_coefficient"}, pre)
    default = TorqueSplit()
    split = TorqueSplit(
        a_opening=rd.number(ts, "a_opening", pre, default=default.a_opening),
        b_opening=rd.number(ts, "b_opening", pre, lo=0.0, default=default.b_opening),
        a_closing=rd.number(ts, "a_closing", pre, default=default.a_closing),
        b_closing=rd.number(ts, "b_closing", pre, lo=0.0, default=default.b_closing),
        friction_coefficient=rd.number(ts, "friction_coefficient", pre, lo=0.01, hi=2.0,
                                       default=default.friction_coefficient),
    )
    return Tune(name=name, drive=drive, primary_spring=primary_spring,
                secondary_spring=secondary_spring, helix=helix, primary_actuator=actuator,
                flyweights=flyweights, roller_track=roller, torque_split=split, notes=notes)


def load_tune(path: str | Path) -> Tune:
    """Read and validate a tune TOML file (the only I/O in this module)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(path, "<file>", f"a readable tune file ({exc.strerror})") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(path, "<toml>", f"valid TOML ({exc})") from None
    return tune_from_dict(data, path)


def _tune_to_dict(t: Tune) -> dict[str, Any]:
    out: dict[str, Any] = {"schema": SCHEMA, "name": t.name}
    if t.notes:
        out["notes"] = t.notes
    out["drive"] = dataclasses.asdict(t.drive)
    prim: dict[str, Any] = {"actuator": t.primary_actuator}
    if t.flyweights is not None:
        fw = dataclasses.asdict(t.flyweights)
        if not fw["washer_mass_each_kg"]:
            del fw["washer_mass_each_kg"]
        fw["sheave_travel_m"] = list(fw["sheave_travel_m"])
        fw["radius_m"] = list(fw["radius_m"])
        prim["flyweights"] = fw
    if t.roller_track is not None:
        prim["roller_track"] = dataclasses.asdict(t.roller_track)
    prim["spring"] = dataclasses.asdict(t.primary_spring)
    out["primary"] = prim
    out["secondary"] = {
        "spring": dataclasses.asdict(t.secondary_spring),
        "helix": {"angle_deg": t.helix.angle_from_axis_deg, "angle_reference": "axis",
                  "radius_m": t.helix.radius_m},
        "torque_split": dataclasses.asdict(t.torque_split),
    }
    return out


def dumps_tune(t: Tune) -> str:
    """Serialise a tune to TOML text (minimal writer: the layout is fixed and
    shallow, so no third-party TOML writer is needed)."""

    def fmt(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float, np.floating)):
            return repr(float(v)) if not isinstance(v, int) else str(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(fmt(x) for x in v) + "]"
        raise TypeError(type(v))

    lines: list[str] = []

    def emit(table: Mapping[str, Any], prefix: str) -> None:
        scalars = {k: v for k, v in table.items() if not isinstance(v, Mapping)}
        if prefix and scalars:
            lines.append(f"\n[{prefix}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {fmt(v)}")
        for k, v in table.items():
            if isinstance(v, Mapping):
                emit(v, f"{prefix}.{k}" if prefix else k)

    emit(t.to_dict(), "")
    return "\n".join(lines).lstrip("\n") + "\n"


def model_params_for(tune: Tune, belt=None):
    """Belt-model parameters (:class:`dyno.model.params.ModelParams`) for a tune: its drive geometry with the
    thesis belt (Table 6.1) unless ``belt`` (a ``BeltParams``) is given.  The parts as measured: the simulated
    rig reads them too (it shares the geometry with the host, not the host's shift model)."""
    from dyno.model.params import BeltParams, DriveParams, ModelParams

    belt = belt or BeltParams()
    if belt.pitch_length_m != tune.drive.belt_pitch_length_m:
        belt = replace(belt, pitch_length_m=tune.drive.belt_pitch_length_m)
    return ModelParams(belt=belt, drive=DriveParams(centre_distance_m=tune.drive.centre_distance_m,
                                                    sheave_half_angle_deg=tune.drive.sheave_half_angle_deg))
