"""rig.toml ``[ambient]``: the rig's air — an ambient sensor on its I²C bus, or a day given by hand.

Split from :mod:`dyno.rigconfig` (which validates the rest of the file with the same reader).

``sensor = "bme280"`` (with ``address``, 0x76 or 0x77) has the run read the air at its start and end;
``sensor = "none"`` (the shipped file) leaves it to ``temp_c``/``pressure_kpa``/``rh_pct`` here or
``--ambient`` on the command line; with neither the run is *uncorrected* (docs/analysis.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping


@dataclass(frozen=True)
class AmbientConfig:
    sensor: str = "none"  # "none" | "bme280"
    address: int = 0x76
    temp_c: float | None = None  # a given day (station pressure, as a barometer reads it)
    pressure_kpa: float | None = None
    rh_pct: float | None = None

    def given(self):
        """The day given here, as :class:`dyno.analysis.air.Ambient` (None without one)."""
        from dyno.analysis.air import Ambient

        if self.temp_c is None or self.pressure_kpa is None:
            return None
        return Ambient(self.temp_c, self.pressure_kpa, self.rh_pct, "given")


def ambient_table(r, data: Mapping) -> AmbientConfig:
    t = data.get("ambient", {})
    if not isinstance(t, Mapping):
        raise r.err("ambient", f"expected a table [ambient], got {type(t).__name__}")
    r.no_extra(t, {"sensor", "address", "temp_c", "pressure_kpa", "rh_pct"}, "ambient.")
    cfg = AmbientConfig(
        sensor=r.string(t, "sensor", "ambient.", choices=("none", "bme280"), required=False, default="none"),
        address=r.integer(t, "address", "ambient.", lo=0x76, hi=0x77, required=False, default=0x76, hexfmt=True),
        temp_c=r.number(t, "temp_c", "ambient.", lo=-40.0, hi=60.0, required=False, default=None),
        pressure_kpa=r.number(t, "pressure_kpa", "ambient.", lo=50.0, hi=110.0, required=False, default=None),
        rh_pct=r.number(t, "rh_pct", "ambient.", lo=0.0, hi=100.0, required=False, default=None))
    if (cfg.temp_c is None) != (cfg.pressure_kpa is None):
        raise r.err("ambient.pressure_kpa" if cfg.pressure_kpa is None else "ambient.temp_c",
                    "both temp_c and pressure_kpa for a given day (or neither)")
    return cfg
