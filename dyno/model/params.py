"""Belt, drive and operating-point parameters of the belt model.

Defaults are the thesis's Table 6.1 case (Messick 2018): a CVTech BD52-2172-S
rubber belt on a Baja SAE CVT at a 1:1 geometric ratio, 3400 rpm, 18 N*m and
100 N slack-span tractive tension.  Table 6.1 prints EI in N/m^2; the unit is
N*m^2 (see docs/belt-model.md, errata).

Every name carries its unit.  The dataclasses are frozen so a parameter set
can be hashed (the overlay cache keys on it) and shared between threads.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

from dyno.errors import ConfigError

#: ``path`` reported by :class:`~dyno.errors.ConfigError` for model inputs.
INPUT_PATH = "belt-model input"

VARIANTS = ("corrected", "as_published")


def bad_input(field_name: str, expected: str) -> ConfigError:
    """Build the :class:`ConfigError` the model raises for a bad input."""
    return ConfigError(INPUT_PATH, field_name, expected)


def _check_positive(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise bad_input(name, f"a finite positive number, got {value!r}")


@dataclass(frozen=True)
class BeltParams:
    """Rubber V-belt properties (thesis Section 4, Table 6.1)."""

    pitch_length_m: float = 0.8572
    axial_stiffness_n: float = 243.5e3  # EA: force per unit strain
    bending_stiffness_nm2: float = 0.2602  # EI
    radial_stiffness_n_m2: float = 18.71e6  # k: axial force per length per radial penetration (eq 3.16)
    mass_per_length_kg_m: float = 0.4375  # m_o; the appendix code's value (text rounds to 0.437)
    friction_coefficient: float = 0.4  # kinetic, belt on sheave

    def __post_init__(self):
        for name, value in asdict(self).items():
            _check_positive(name, value)


@dataclass(frozen=True)
class DriveParams:
    """Fixed-centre CVT geometry."""

    centre_distance_m: float = 0.214
    sheave_half_angle_deg: float = 12.0  # beta, half the groove angle

    def __post_init__(self):
        _check_positive("centre_distance_m", self.centre_distance_m)
        if not (0.5 <= self.sheave_half_angle_deg <= 45.0):
            raise bad_input("sheave_half_angle_deg", f"between 0.5 and 45 degrees, got {self.sheave_half_angle_deg!r}")

    @property
    def sheave_half_angle_rad(self) -> float:
        return math.radians(self.sheave_half_angle_deg)


@dataclass(frozen=True)
class OperatingPoint:
    """Where the drive runs.

    ``ratio`` is the geometric ratio R_S/R_P (= ideal primary rpm / secondary
    rpm; 1.74 is low gear, 0.72 overdrive).  Exactly one of
    ``slack_tension_n`` (slack-span tractive tension at the primary exit, as in
    the thesis) and ``primary_axial_force_n`` (as in its validation chapter)
    sets the tension level.
    """

    ratio: float = 1.0
    primary_speed_rpm: float = 3400.0
    primary_torque_nm: float = 18.0
    slack_tension_n: float | None = 100.0
    primary_axial_force_n: float | None = None

    def __post_init__(self):
        _check_positive("ratio", self.ratio)
        _check_positive("primary_speed_rpm", self.primary_speed_rpm)
        if not (math.isfinite(self.primary_torque_nm) and self.primary_torque_nm > 0):
            raise bad_input("primary_torque_nm", f"a finite positive torque (the primary drives), got {self.primary_torque_nm!r}")
        given = [v is not None for v in (self.slack_tension_n, self.primary_axial_force_n)]
        if sum(given) != 1:
            raise bad_input("slack_tension_n/primary_axial_force_n", "exactly one of the two")
        if self.slack_tension_n is not None:
            _check_positive("slack_tension_n", self.slack_tension_n)
        if self.primary_axial_force_n is not None:
            _check_positive("primary_axial_force_n", self.primary_axial_force_n)

    @property
    def primary_speed_rad_s(self) -> float:
        return self.primary_speed_rpm * 2.0 * math.pi / 60.0

    @property
    def boundary_condition(self) -> str:
        return "slack_tension" if self.slack_tension_n is not None else "primary_axial_force"


@dataclass(frozen=True)
class ModelParams:
    """Everything the steady model needs apart from the operating point."""

    belt: BeltParams = field(default_factory=BeltParams)
    drive: DriveParams = field(default_factory=DriveParams)

    def with_sheave_angle(self, sheave_half_angle_deg: float, scale_radial_stiffness: bool = True) -> "ModelParams":
        """Same belt in a groove of another angle (thesis Section 7.1).

        The measured quantity is force per displacement per sample length, so
        k scales with tan(beta) (eq 7.1) when ``scale_radial_stiffness``.
        """
        belt = self.belt
        if scale_radial_stiffness:
            k = belt.radial_stiffness_n_m2 * math.tan(math.radians(sheave_half_angle_deg)) / math.tan(
                self.drive.sheave_half_angle_rad
            )
            belt = replace(belt, radial_stiffness_n_m2=k)
        return ModelParams(belt=belt, drive=replace(self.drive, sheave_half_angle_deg=sheave_half_angle_deg))

    def with_belt(self, **changes) -> "ModelParams":
        return ModelParams(belt=replace(self.belt, **changes), drive=self.drive)

    def as_dict(self) -> dict:
        return {"belt": asdict(self.belt), "drive": asdict(self.drive)}


TABLE_6_1 = ModelParams()
TABLE_6_1_POINT = OperatingPoint()
