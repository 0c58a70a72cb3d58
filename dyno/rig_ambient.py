"""rig.toml ``[ambient]``: the rig's air — an ambient sensor on its I²C bus, or a day given by hand.

Split from :mod:`dyno.rigconfig` (which validates the rest of the file with the same reader).

``sensor = "bme280"`` (the shipped file; ``address`` 0x76 or 0x77) has the run read the air at its start and end;
``sensor = "none"`` (a rig without one; also a file with no ``[ambient]``) leaves it to ``temp_c``/``pressure_kpa``/``rh_pct`` here or
``--ambient`` on the command line; with neither the run is *uncorrected* (docs/analysis.md).
``altitude_m`` (the rig's site) narrows an uncorrected run's pressure range to the site's ISA figure
± the weather (:func:`dyno.analysis.air.plausible_pressure_kpa`); the simulated day is drawn there too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping


@dataclass(frozen=True)
class AmbientConfig:
    sensor: str = "none"  # "none" | "bme280" (the shipped rig.toml's: the recommended rig measures its air)
    address: int = 0x76
    temp_c: float | None = None  # a given day (station pressure, as a barometer reads it)
    pressure_kpa: float | None = None
    rh_pct: float | None = None
    altitude_m: float | None = None  # the rig's site (narrows the pressure an uncorrected run allows)

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
    r.no_extra(t, {"sensor", "address", "temp_c", "pressure_kpa", "rh_pct", "altitude_m"}, "ambient.")
    cfg = AmbientConfig(
        sensor=r.string(t, "sensor", "ambient.", choices=("none", "bme280"), required=False, default="none"),
        address=r.integer(t, "address", "ambient.", lo=0x76, hi=0x77, required=False, default=0x76, hexfmt=True),
        temp_c=r.number(t, "temp_c", "ambient.", lo=-40.0, hi=60.0, required=False, default=None),
        pressure_kpa=r.number(t, "pressure_kpa", "ambient.", lo=50.0, hi=110.0, required=False, default=None),
        rh_pct=r.number(t, "rh_pct", "ambient.", lo=0.0, hi=100.0, required=False, default=None),
        altitude_m=r.number(t, "altitude_m", "ambient.", lo=-400.0, hi=4000.0, required=False, default=None))
    if (cfg.temp_c is None) != (cfg.pressure_kpa is None):
        raise r.err("ambient.pressure_kpa" if cfg.pressure_kpa is None else "ambient.temp_c",
                    "both temp_c and pressure_kpa for a given day (or neither)")
    return cfg
