"""The numerical CVT design method's inputs (Arango & Munoz 2020): requirements and belt sections, and
their file readers (TOML requirements, CSV belt catalogue; one-line errors naming file and field).
The method itself: :mod:`dyno.tuning.design`."""

from __future__ import annotations

import csv
import dataclasses
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping


from dyno.errors import ConfigError

G_M_S2 = 9.81
REQ_SCHEMA = "dyno.design-requirements/1"


# ------------------------------------------------------------------ inputs


@dataclass(frozen=True)
class BeltSection:
    """One row of the belt catalogue (``calibration/belt_catalogue.csv``).

    ``bending_constant_n_mm`` is K_b of the bending tension ``F_b = K_b / d``
    (see :func:`bending_tension_n`).
    """

    section: str
    top_width_mm: float
    thickness_mm: float
    belt_angle_deg: float
    area_mm2: float
    density_kg_per_dm3: float
    bending_constant_n_mm: float
    source: str = ""


@dataclass(frozen=True)
class Requirements:
    """Route, vehicle, motor and designer choices (Sections 2.1-2.12)."""

    name: str
    # route / performance (2.1)
    max_slope_deg: float
    top_speed_slope_km_h: float
    top_speed_flat_km_h: float
    climb_acceleration_m_s2: float
    # vehicle
    mass_kg: float
    drag_coefficient: float
    frontal_area_m2: float
    air_density_kg_m3: float
    rolling_coefficient: float
    wheel_diameter_m: float
    driveline_efficiency: float
    # motor / engine (2.2)
    max_torque_nm: float
    max_torque_speed_rpm: float
    torque_at_max_power_nm: float
    max_speed_rpm: float
    accessory_power_kw: float = 0.0
    # CVT choices (2.3-2.9)
    ratio_min: float = 1.0
    belt_friction_coefficient: float = 0.5
    belt_tensile_strength_n_per_mm2: float = 4.0
    min_wrap_angle_deg: float = 160.0
    shift_start_rpm: float = 1500.0
    shift_end_rpm: float = 2500.0
    torque_at_shift_end_nm: float = 200.0
    driver_min_diameter_mm: float | None = None  # override of eq. 8
    centre_distance_mm: float | None = None  # override of eq. 18
    driven_sheave_angle_deg: float | None = None  # 2.8 anti-crossing change
    # actuators (2.10-2.12)
    n_steps: int = 50
    weight_radius_start_mm: float = 40.0
    weight_radius_end_mm: float = 120.0
    flyweight_mass_kg: float = 0.1
    flyweight_pivot_radius_mm: float = 80.0
    flyweight_cg_arm_mm: float = 30.0
    flyweight_start_angle_deg: float = 20.0
    follower_offset_mm: tuple[float, float] = (-10.0, 25.0)
    spring_mean_diameter_mm: float = 70.0
    spring_wire_diameter_mm: float = 14.0
    spring_shear_modulus_n_per_mm2: float = 79300.0
    spring_precompression_mm: float = 10.0
    cam_diameter_mm: float = 150.0


# ----------------------------------------------------------------- loaders

_REQ_TABLES = {
    "route": ("max_slope_deg", "top_speed_slope_km_h", "top_speed_flat_km_h", "climb_acceleration_m_s2"),
    "vehicle": ("mass_kg", "drag_coefficient", "frontal_area_m2", "air_density_kg_m3", "rolling_coefficient",
                "wheel_diameter_m", "driveline_efficiency"),
    "motor": ("max_torque_nm", "max_torque_speed_rpm", "torque_at_max_power_nm", "max_speed_rpm",
              "accessory_power_kw"),
    "cvt": ("ratio_min", "belt_friction_coefficient", "belt_tensile_strength_n_per_mm2", "min_wrap_angle_deg",
            "shift_start_rpm", "shift_end_rpm", "torque_at_shift_end_nm", "driver_min_diameter_mm",
            "centre_distance_mm", "driven_sheave_angle_deg"),
    "actuators": ("n_steps", "weight_radius_start_mm", "weight_radius_end_mm", "flyweight_mass_kg",
                  "flyweight_pivot_radius_mm", "flyweight_cg_arm_mm", "flyweight_start_angle_deg",
                  "follower_offset_mm", "spring_mean_diameter_mm", "spring_wire_diameter_mm",
                  "spring_shear_modulus_n_per_mm2", "spring_precompression_mm", "cam_diameter_mm"),
}
_OPTIONAL = {f.name for f in dataclasses.fields(Requirements)
             if f.default is not dataclasses.MISSING}


def requirements_from_dict(data: Mapping[str, Any], path: str | Path = "<requirements>") -> Requirements:
    """Validate a parsed requirements mapping (raises ConfigError)."""
    path = str(path)
    allowed_top = {"schema", "name", *(_REQ_TABLES)}
    for key in data:
        if key not in allowed_top:
            raise ConfigError(path, key, f"unknown key (allowed: {', '.join(sorted(allowed_top))})")
    if data.get("schema", REQ_SCHEMA) != REQ_SCHEMA:
        raise ConfigError(path, "schema", f"{REQ_SCHEMA!r}")
    kwargs: dict[str, Any] = {"name": str(data.get("name", Path(path).stem))}
    for table, keys in _REQ_TABLES.items():
        sub = data.get(table, {})
        if not isinstance(sub, Mapping):
            raise ConfigError(path, table, "a table")
        for key in sub:
            if key not in keys:
                raise ConfigError(path, f"{table}.{key}", f"unknown key (allowed: {', '.join(keys)})")
        for key in keys:
            fld = f"{table}.{key}"
            if key not in sub:
                if key in _OPTIONAL:
                    continue
                raise ConfigError(path, fld, "missing number")
            val = sub[key]
            if key == "follower_offset_mm":
                if (not isinstance(val, list) or len(val) != 2
                        or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in val)):
                    raise ConfigError(path, fld, "[radial_mm, axial_mm]")
                kwargs[key] = (float(val[0]), float(val[1]))
                continue
            if key == "n_steps":
                if isinstance(val, bool) or not isinstance(val, int) or val < 2:
                    raise ConfigError(path, fld, "an integer >= 2")
                kwargs[key] = val
                continue
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
                raise ConfigError(path, fld, f"a finite number, got {val!r}")
            if key not in ("max_slope_deg",) and val < 0:
                raise ConfigError(path, fld, f">= 0, got {val}")
            kwargs[key] = float(val)
    req = Requirements(**kwargs)
    if not 0 < req.driveline_efficiency <= 1:
        raise ConfigError(path, "vehicle.driveline_efficiency", "in (0, 1]")
    if not 0 < req.min_wrap_angle_deg < 180:
        raise ConfigError(path, "cvt.min_wrap_angle_deg", "in (0, 180)")
    if req.shift_end_rpm <= req.shift_start_rpm:
        raise ConfigError(path, "cvt.shift_end_rpm", "greater than cvt.shift_start_rpm")
    for key in ("mass_kg", "wheel_diameter_m", "max_torque_nm", "torque_at_max_power_nm",
                "belt_friction_coefficient", "belt_tensile_strength_n_per_mm2", "ratio_min"):
        if getattr(req, key) <= 0:
            raise ConfigError(path, key, "> 0")
    return req


def load_requirements(path: str | Path) -> Requirements:
    """Read a requirements TOML file."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(path, "<file>", f"a readable requirements file ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(path, "<toml>", f"valid TOML ({exc})") from None
    return requirements_from_dict(data, path)


_CAT_FIELDS = ("section", "top_width_mm", "thickness_mm", "belt_angle_deg", "area_mm2",
               "density_kg_per_dm3", "bending_constant_n_mm", "source")


def load_belt_catalogue(path: str | Path) -> list[BeltSection]:
    """Read the belt catalogue CSV (header: see ``_CAT_FIELDS``)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(path, "<file>", f"a readable catalogue ({exc.strerror})") from None
    rows = [r for r in csv.DictReader(line for line in text.splitlines() if not line.startswith("#"))]
    if not rows:
        raise ConfigError(path, "<rows>", "at least one belt section")
    out = []
    for n, row in enumerate(rows, start=2):
        missing = [f for f in _CAT_FIELDS[:-1] if f not in row or row[f] in (None, "")]
        if missing:
            raise ConfigError(path, f"row {n}.{missing[0]}", "a value")
        try:
            nums = [float(row[f]) for f in _CAT_FIELDS[1:-1]]
        except ValueError:
            raise ConfigError(path, f"row {n}", "numbers in every numeric column") from None
        if any(x <= 0 for x in nums):
            raise ConfigError(path, f"row {n}", "positive numbers")
        out.append(BeltSection(row["section"], *nums, source=row.get("source") or ""))
    return out
