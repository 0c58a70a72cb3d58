"""The parts catalogue (``calibration/parts/*.toml``): the CVT parts a team can fit.

Four kinds, each an array of tables in a ``dyno.parts/1`` file (docs/tuning.md "Parts catalogue"):

* ``[[flyweights]]``: ``count``, ``mass_each_kg``, ``profile`` (a ``[profiles.NAME]`` table of the
  same file: ``sheave_travel_m``, ``radius_m``; omitted = the tune's own profile);
* ``[[primary_springs]]``: ``rate_n_per_m`` and one of ``preload_n`` / ``force_at_full_shift_n``;
* ``[[secondary_springs]]``: ``preload_n``, ``rate_n_per_m``, ``torsion_rate_nm_per_rad`` and
  ``torsion_preload_positions_nm`` (each position is a candidate of its own, ``ID@POSITION``);
* ``[[helixes]]``: ``angle_deg``, ``angle_reference`` (``axis`` | ``rotation_plane``), ``radius_m``.

Every part has ``id``, ``label``, ``source``, ``tolerance_rel`` (its true value within label x
(1 +- tolerance_rel); default 0.1) and ``fits`` (the clutch family; default the file's ``fits``);
``incompatible_with`` lists ids it cannot be fitted with. A bad file raises ConfigError naming the
file and the dotted field.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from dyno.errors import ConfigError

SCHEMA = "dyno.parts/1"
KINDS = {"flyweights": "flyweights", "primary_springs": "primary_spring",
         "secondary_springs": "secondary_spring", "helixes": "helix"}
#: per kind: the labelled fields whose true values differ from the label (the advisor calibrates these)
DEVIATED: dict[str, tuple[str, ...]] = {
    "flyweights": ("mass_each_kg",), "primary_spring": ("preload_n", "rate_n_per_m"),
    "secondary_spring": ("preload_n", "rate_n_per_m"), "helix": ("angle_from_axis_deg",)}
DEFAULT_TOLERANCE_REL = 0.1
_COMMON = {"id", "label", "source", "tolerance_rel", "fits", "incompatible_with"}
_FIELDS = {
    "flyweights": {"count", "mass_each_kg", "washer_mass_each_kg", "profile"},
    "primary_springs": {"rate_n_per_m", "preload_n", "force_at_full_shift_n"},
    "secondary_springs": {"preload_n", "rate_n_per_m", "torsion_rate_nm_per_rad", "torsion_preload_positions_nm",
                          "torsion_preload_nm"},
    "helixes": {"angle_deg", "angle_reference", "radius_m"},
}


@dataclass(frozen=True)
class Part:
    kind: str            # flyweights | primary_spring | secondary_spring | helix (the tune attribute)
    id: str
    label: str
    fits: str
    values: tuple        # ((field, value), ...) in the part's own terms (see apply_part)
    tolerance_rel: float
    source: str
    file: str
    incompatible_with: tuple[str, ...] = ()

    def value(self, name: str, default: Any = None) -> Any:
        return dict(self.values).get(name, default)


def _num(path, fld, v, lo=None, lo_open=False, hi=None) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ConfigError(path, fld, f"a finite number, got {v!r}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ConfigError(path, fld, f"{'>' if lo_open else '>='} {lo:g}, got {v!r}")
    if hi is not None and v > hi:
        raise ConfigError(path, fld, f"<= {hi:g}, got {v!r}")
    return float(v)


def _nums(path, fld, v, min_len=1) -> tuple[float, ...]:
    if not isinstance(v, list) or len(v) < min_len:
        raise ConfigError(path, fld, f"an array of at least {min_len} numbers")
    return tuple(_num(path, fld, x) for x in v)


def _str(path, fld, v) -> str:
    if not isinstance(v, str) or not v:
        raise ConfigError(path, fld, "a non-empty string")
    return v


def parts_from_dict(data: Mapping[str, Any], path: str | Path = "<parts>") -> list[Part]:
    path = str(path)
    allowed = {"schema", "fits", "profiles", *KINDS}
    for k in data:
        if k not in allowed:
            raise ConfigError(path, k, f"unknown key (allowed: {', '.join(sorted(allowed))})")
    if data.get("schema", SCHEMA) != SCHEMA:
        raise ConfigError(path, "schema", f"{SCHEMA!r}, got {data.get('schema')!r}")
    file_fits = _str(path, "fits", data["fits"]) if "fits" in data else None
    profiles: dict[str, tuple] = {}
    for name, tab in (data.get("profiles") or {}).items():
        pre = f"profiles.{name}"
        if not isinstance(tab, Mapping) or set(tab) != {"sheave_travel_m", "radius_m"}:
            raise ConfigError(path, pre, "a table of sheave_travel_m and radius_m")
        t, r = _nums(path, pre + ".sheave_travel_m", tab["sheave_travel_m"], 2), _nums(path, pre + ".radius_m",
                                                                                        tab["radius_m"], 2)
        if len(t) != len(r) or t[0] != 0.0 or any(b <= a for a, b in zip(t, t[1:])) or min(r) <= 0:
            raise ConfigError(path, pre, "sheave_travel_m strictly increasing from 0, radius_m positive, same length")
        profiles[name] = (t, r)
    out: list[Part] = []
    for key, kind in KINDS.items():
        rows = data.get(key, [])
        if not isinstance(rows, list):
            raise ConfigError(path, key, "an array of tables ([[" + key + "]])")
        for i, row in enumerate(rows):
            pre = f"{key}[{i}]"
            if not isinstance(row, Mapping):
                raise ConfigError(path, pre, "a table")
            for k in row:
                if k not in _COMMON | _FIELDS[key]:
                    raise ConfigError(path, f"{pre}.{k}",
                                      f"unknown key (allowed: {', '.join(sorted(_COMMON | _FIELDS[key]))})")
            pid = _str(path, pre + ".id", row.get("id"))
            fits = _str(path, pre + ".fits", row.get("fits", file_fits))
            tol = _num(path, pre + ".tolerance_rel", row.get("tolerance_rel", DEFAULT_TOLERANCE_REL), lo=0.0, hi=0.5)
            inc = row.get("incompatible_with", [])
            if not isinstance(inc, list) or not all(isinstance(x, str) for x in inc):
                raise ConfigError(path, pre + ".incompatible_with", "an array of part ids")
            common = dict(label=str(row.get("label", pid)), fits=fits, tolerance_rel=tol,
                          source=_str(path, pre + ".source", row.get("source")), file=path,
                          incompatible_with=tuple(inc))

            def need(f, **kw):
                if f not in row:
                    raise ConfigError(path, f"{pre}.{f}", "missing number")
                return _num(path, f"{pre}.{f}", row[f], **kw)

            if key == "flyweights":
                count = row.get("count")
                if isinstance(count, bool) or not isinstance(count, int) or count < 1:
                    raise ConfigError(path, pre + ".count", f"an integer >= 1, got {count!r}")
                mass = need("mass_each_kg", lo=0.0, lo_open=True, hi=5.0)
                vals = [("count", count), ("mass_each_kg", mass)]
                if "washer_mass_each_kg" in row:  # tuning washers on a body: the body is the same part
                    w = _num(path, pre + ".washer_mass_each_kg", row["washer_mass_each_kg"], lo=0.0)
                    if w >= mass:
                        raise ConfigError(path, pre + ".washer_mass_each_kg", f"less than mass_each_kg, got {w:g}")
                    vals.append(("washer_mass_each_kg", w))
                if "profile" in row:
                    prof = row["profile"]
                    if prof not in profiles:
                        raise ConfigError(path, pre + ".profile", f"a [profiles.NAME] of this file, got {prof!r}")
                    vals += [("sheave_travel_m", profiles[prof][0]), ("radius_m", profiles[prof][1])]
                out.append(Part(kind, pid, values=tuple(vals), **common))
            elif key == "primary_springs":
                if ("preload_n" in row) == ("force_at_full_shift_n" in row):
                    raise ConfigError(path, pre + ".preload_n", "exactly one of preload_n or force_at_full_shift_n")
                f = "preload_n" if "preload_n" in row else "force_at_full_shift_n"
                vals = (("rate_n_per_m", need("rate_n_per_m", lo=0.0)), (f, need(f, lo=0.0)))
                out.append(Part(kind, pid, values=vals, **common))
            elif key == "secondary_springs":
                base = [("preload_n", need("preload_n", lo=0.0)), ("rate_n_per_m", need("rate_n_per_m", lo=0.0)),
                        ("torsion_rate_nm_per_rad", _num(path, pre + ".torsion_rate_nm_per_rad",
                                                         row.get("torsion_rate_nm_per_rad", 0.0), lo=0.0))]
                if "torsion_preload_positions_nm" in row:
                    positions = _nums(path, pre + ".torsion_preload_positions_nm", row["torsion_preload_positions_nm"])
                    for q in positions:
                        if q < 0:
                            raise ConfigError(path, pre + ".torsion_preload_positions_nm", "numbers >= 0")
                        out.append(Part(kind, f"{pid}@{q:g}", values=tuple(base + [("torsion_preload_nm", q)]),
                                        **{**common, "label": f"{common['label']}, position {q:g} N m"}))
                else:
                    q = _num(path, pre + ".torsion_preload_nm", row.get("torsion_preload_nm", 0.0), lo=0.0)
                    out.append(Part(kind, pid, values=tuple(base + [("torsion_preload_nm", q)]), **common))
            else:
                ref = row.get("angle_reference", "axis")
                if ref not in ("axis", "rotation_plane"):
                    raise ConfigError(path, pre + ".angle_reference", f"'axis' or 'rotation_plane', got {ref!r}")
                angle = need("angle_deg", lo=0.0, lo_open=True, hi=89.0)
                vals = (("angle_from_axis_deg", angle if ref == "axis" else 90.0 - angle),
                        ("radius_m", need("radius_m", lo=0.0, lo_open=True)))
                out.append(Part(kind, pid, values=vals, **common))
    return out


def load_catalogue(directory: str | Path) -> list[Part]:
    """Every ``*.toml`` of ``directory``; duplicate ids across files are an error."""
    directory = Path(directory)
    if not directory.is_dir():
        raise ConfigError(directory, "<dir>", "a directory of parts catalogue files (*.toml)")
    parts: list[Part] = []
    seen: dict[str, str] = {}
    files = sorted(directory.glob("*.toml"))
    if not files:
        raise ConfigError(directory, "<dir>", "at least one parts catalogue file (*.toml)")
    for f in files:
        try:
            data = tomllib.loads(f.read_text(encoding="utf-8"))
        except OSError as exc:
            raise ConfigError(f, "<file>", f"a readable file ({exc.strerror})") from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f, "<toml>", f"valid TOML ({exc})") from None
        for p in parts_from_dict(data, f):
            if p.id in seen and seen[p.id] != str(f):
                raise ConfigError(f, p.id, f"a part id not already used in {seen[p.id]}")
            if p.id in seen:
                continue  # the same id twice in one file: the first stands (e.g. a profile repeated)
            seen[p.id] = str(f)
            parts.append(p)
    return parts


# ------------------------------------------------------------------ tunes and parts


def apply_part(tune, part: Part):
    """The tune with ``part`` fitted (a new name is the caller's business)."""
    from dyno.tuning import actuators as act

    v = dict(part.values)
    attr = part.kind
    if attr == "primary_spring" and "force_at_full_shift_n" in v:
        v = {"rate_n_per_m": v["rate_n_per_m"],
             "preload_n": v["force_at_full_shift_n"] - v["rate_n_per_m"] * act.primary_full_travel_m(tune)}
    if attr == "flyweights" and tune.flyweights is None:
        raise ConfigError(part.file, part.id, "a tune with sliding flyweights (this one has a roller track)")
    if attr == "flyweights":
        v.setdefault("washer_mass_each_kg", 0.0)  # a set without washers takes the old set's off
    return tune.with_changes(**{f"{attr}.{k}": (tuple(x) if isinstance(x, (list, tuple)) else x)
                                for k, x in v.items()})


def part_identity(tune, kind: str, *, with_settings: bool = False) -> str:
    """The labelled values that identify the ``kind`` part of a tune (same physical part, same identity:
    what its deviation and calibration belong to).  ``with_settings`` adds how it is set up (a secondary
    spring's torsion preload: the position it is clocked to), which tells tunes apart."""
    obj = getattr(tune, kind)
    if obj is None:
        return f"{kind}:none"
    fields = {"flyweights": ("count", "body_mass_each_kg", "radius_m"),  # the body: washers are additions
              "primary_spring": ("preload_n", "rate_n_per_m"),
              "secondary_spring": ("preload_n", "rate_n_per_m", "torsion_rate_nm_per_rad"),
              "helix": ("angle_from_axis_deg", "radius_m")}[kind]
    if with_settings:
        fields = fields + {"flyweights": ("washer_mass_each_kg",),
                           "secondary_spring": ("torsion_preload_nm",)}.get(kind, ())
    vals = []
    for f in fields:
        x = getattr(obj, f)
        vals.append(",".join(f"{y:.5g}" for y in x) if isinstance(x, tuple) else f"{x:.5g}")
    return f"{kind}:" + ";".join(vals)


def match_parts(tune, catalogue: list[Part]) -> dict[str, Part | None]:
    """For each kind, the catalogue part the tune carries (None: not in the catalogue)."""
    out: dict[str, Part | None] = {}
    for kind in DEVIATED:
        ident = part_identity(tune, kind, with_settings=True)
        out[kind] = next((p for p in catalogue if p.kind == kind
                          and part_identity(apply_part(tune, p), kind, with_settings=True) == ident), None)
    return out
