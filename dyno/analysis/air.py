"""SAE J1349 power correction and the air it needs (pure).  Used by the engine map
(:meth:`dyno.analysis.engine_map.EngineMap.at_ambient`)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

#: SAE J1349 reference conditions: 25 °C intake air, 99 kPa dry-air pressure.
J1349_REFERENCE_TEMP_C = 25.0
J1349_REFERENCE_DRY_PRESSURE_KPA = 99.0


def j1349_correction_factor(temp_c: float, dry_pressure_kpa: float) -> float:
    """SAE J1349 (1990) power correction factor for spark-ignition engines.

    .. math:: CF = 1.176 \\, \\frac{99}{p_d} \\sqrt{\\frac{T + 273}{298}} - 0.176

    Reference conditions: intake air at 25 °C (298 K) and 99 kPa *dry-air*
    partial pressure (total 100 kPa less water vapour), where CF = 1.
    Standard power = observed power × CF.  The 0.176 term accounts for the
    ~15 % of indicated power lost to friction, which does not scale with
    air density.  (The 2004 revision rounds to 1.18/0.18.)

    Parameters
    ----------
    temp_c : float
        Intake air temperature, °C.
    dry_pressure_kpa : float
        Dry-air partial pressure, kPa (see :func:`dry_air_pressure_kpa`).
    """
    t = float(temp_c)
    p = float(dry_pressure_kpa)
    if not (math.isfinite(t) and -60.0 < t < 80.0):
        raise ValueError(f"j1349_correction_factor: temp_c {temp_c!r} is not a plausible air "
                         f"temperature (-60..80 C)")
    if not (math.isfinite(p) and 30.0 < p < 120.0):
        raise ValueError(f"j1349_correction_factor: dry_pressure_kpa {dry_pressure_kpa!r} is not "
                         f"plausible (30..120 kPa); is it in kPa?")
    return 1.176 * (J1349_REFERENCE_DRY_PRESSURE_KPA / p) * math.sqrt((t + 273.0) / 298.0) - 0.176


def saturation_vapour_pressure_kpa(temp_c: float) -> float:
    """Saturation vapour pressure of water over liquid, kPa (Buck 1996).

    .. math:: e_s = 0.61121 \\exp\\left[\\left(18.678 - \\frac{T}{234.5}\\right)
              \\frac{T}{257.14 + T}\\right]

    Accurate to ~0.05 % from -40 to 50 °C (Buck's improved Magnus form).
    """
    t = float(temp_c)
    return 0.61121 * math.exp((18.678 - t / 234.5) * (t / (257.14 + t)))


def dry_air_pressure_kpa(total_pressure_kpa: float, temp_c: float,
                         relative_humidity_pct: float) -> float:
    """Dry-air partial pressure from barometer, temperature and humidity.

    .. math:: p_d = p - \\frac{RH}{100} e_s(T)

    Parameters
    ----------
    total_pressure_kpa : float
        Station (not sea-level-corrected) barometric pressure, kPa.
    temp_c : float
        Air temperature, °C.
    relative_humidity_pct : float
        Relative humidity, 0–100 %.
    """
    rh = float(relative_humidity_pct)
    if not (math.isfinite(rh) and 0.0 <= rh <= 100.0):
        raise ValueError(f"dry_air_pressure_kpa: relative_humidity_pct must be in [0, 100], "
                         f"got {relative_humidity_pct!r}")
    p = float(total_pressure_kpa)
    if not (math.isfinite(p) and p > 0):
        raise ValueError(f"dry_air_pressure_kpa: total_pressure_kpa must be > 0, got {p!r}")
    return p - rh / 100.0 * saturation_vapour_pressure_kpa(temp_c)


# ---------------------------------------------------------------------------------------------------
# The run's air: where it came from, its J1349 factor, and the uncertainty it leaves in efficiency

#: A plausible day when nothing says what the air was (a run "uncorrected"): intake air −10…45 °C,
#: station pressure 80…105 kPa (sea level to ~2,000 m, with weather), water vapour 0…4 kPa (a dew point
#: up to ~29 °C; beyond that is rare weather anywhere a Baja team tests).
PLAUSIBLE_TEMP_C = (-10.0, 45.0)
PLAUSIBLE_PRESSURE_KPA = (80.0, 105.0)
PLAUSIBLE_VAPOUR_KPA = (0.0, 4.0)

#: What a given or sensed day is known to (rectangular half-widths): a BME280's absolute accuracy
#: (data sheet: ±1 °C, ±1 hPa, ±3 %RH); a thermometer and barometer read by hand are no better.
AIR_TOLERANCE_TEMP_C = 1.0
AIR_TOLERANCE_PRESSURE_KPA = 0.1
AIR_TOLERANCE_RH_PCT = 3.0
#: Humidity not given: taken as 50 % with ±50 % (rectangular), the whole range.
RH_UNKNOWN_PCT = 50.0


def j1349_factor_of(temp_c: float, pressure_kpa: float, rh_pct: float) -> float:
    """J1349 factor of a day given as a barometer and hygrometer read it (station pressure, RH)."""
    return j1349_correction_factor(temp_c, dry_air_pressure_kpa(pressure_kpa, temp_c, rh_pct))


#: Station pressure at a known site moves with the weather by about this much either side of its ISA figure
#: (a year's 1st..99th percentile at one station is ~±3 kPa; the sim's day draws ±1 kPa sd).
SITE_WEATHER_KPA = 4.0


def isa_pressure_kpa(altitude_m: float) -> float:
    """ISA station pressure at ``altitude_m``: :math:`p = 101.325\\,(1 - 2.25577\\cdot10^{-5} h)^{5.25588}` kPa."""
    return 101.325 * (1.0 - 2.25577e-5 * float(altitude_m)) ** 5.25588


def plausible_pressure_kpa(altitude_m: float | None = None) -> tuple[float, float]:
    """The station pressure a day may have: ``PLAUSIBLE_PRESSURE_KPA``, or the site's (``rig.toml [ambient]
    altitude_m``) ISA figure ± ``SITE_WEATHER_KPA``."""
    if altitude_m is None:
        return PLAUSIBLE_PRESSURE_KPA
    p = isa_pressure_kpa(altitude_m)
    return (p - SITE_WEATHER_KPA, p + SITE_WEATHER_KPA)


@functools.lru_cache(maxsize=8)
def uncorrected_factors(altitude_m: float | None = None, n: int = 256) -> tuple[float, ...]:
    """The distribution of J1349's factor over the plausible day: ``n`` equal-probability quantiles.

    The day is uniform over its stated box (temperature ``PLAUSIBLE_TEMP_C``, station pressure
    :func:`plausible_pressure_kpa`, vapour pressure ``0 … min(4 kPa, e_s(T))``): nothing says one day of
    it is likelier than another, so each is weighted alike (the maximum-entropy choice on a box).  The
    factor is evaluated on a 24 × 24 × 12 midpoint grid of that box and reduced to its quantiles at
    probabilities ``(i + ½)/n``.  Over the default box it spans 0.87…1.40 with 2.5/50/97.5 % quantiles
    0.906/1.081/1.310: the truth is never more than ~10 % below an uncorrected figure, often 30 % above.
    """
    import numpy as np

    lo_p, hi_p = plausible_pressure_kpa(altitude_m)
    t = PLAUSIBLE_TEMP_C[0] + (PLAUSIBLE_TEMP_C[1] - PLAUSIBLE_TEMP_C[0]) * (np.arange(24) + 0.5) / 24
    p = lo_p + (hi_p - lo_p) * (np.arange(24) + 0.5) / 24
    e = (np.arange(12) + 0.5) / 12
    es = 0.61121 * np.exp((18.678 - t / 234.5) * (t / (257.14 + t)))  # saturation_vapour_pressure_kpa
    vap = e[None, :] * np.minimum(PLAUSIBLE_VAPOUR_KPA[1], es)[:, None]  # (T, e)
    dry = p[None, :, None] - vap[:, None, :]  # (T, P, e)
    cf = 1.176 * (J1349_REFERENCE_DRY_PRESSURE_KPA / dry) * np.sqrt((t[:, None, None] + 273.0) / 298.0) - 0.176
    return tuple(float(x) for x in np.quantile(cf.ravel(), (np.arange(n) + 0.5) / n))


def uncorrected_air_rel_u(altitude_m: float | None = None) -> float:
    """Relative standard uncertainty (k = 2 convention: half the 95 % range over 2) of an efficiency whose
    map was NOT taken to the run's air.

    Such an efficiency divides by the standard-day power ``P_std = CF·P_day`` instead of the day's
    ``P_day``, so :math:`\\eta_{true} = P_{out}/P_{day} = CF\\cdot\\eta_{reported}`: the truth is the
    reported figure *times* the unknown day's factor.  Over the plausible day (:func:`uncorrected_factors`)
    CF has 2.5/97.5 % quantiles ``q_lo, q_hi``; the symmetric summary is ``u = (q_hi − q_lo)/4`` (so
    ``2u`` is the range's 95 % half-width).  The interval itself is asymmetric, ``η·[q_lo, q_hi]`` combined
    with the other terms (:func:`dyno.analysis.systematic.interval95`).
    """
    q = uncorrected_factors(altitude_m)
    n = len(q)
    lo, hi = q[int(0.025 * n)], q[min(n - 1, int(0.975 * n))]
    return (hi - lo) / 4.0


def known_air_rel_u(temp_c: float, pressure_kpa: float, rh_pct: float | None) -> float:
    """Relative standard uncertainty of the J1349 factor from what the day is known to.

    Sensitivities by central differences; each tolerance rectangular (``u = a/√3``); an unknown
    humidity is 50 ± 50 %.  Combined in quadrature (the three readings are independent).
    """
    rh = RH_UNKNOWN_PCT if rh_pct is None else rh_pct
    rh_tol = RH_UNKNOWN_PCT if rh_pct is None else AIR_TOLERANCE_RH_PCT
    cf = j1349_factor_of(temp_c, pressure_kpa, rh)
    u2 = 0.0
    for dt, dp, dr in ((AIR_TOLERANCE_TEMP_C, 0, 0), (0, AIR_TOLERANCE_PRESSURE_KPA, 0), (0, 0, rh_tol)):
        hi = j1349_factor_of(temp_c + dt, pressure_kpa + dp, min(100.0, rh + dr))
        lo = j1349_factor_of(temp_c - dt, pressure_kpa - dp, max(0.0, rh - dr))
        u2 += (0.5 * abs(hi - lo) / cf / math.sqrt(3.0)) ** 2
    return math.sqrt(u2)


@dataclass(frozen=True)
class Ambient:
    """The run's intake air and where it came from.

    ``source``: ``"sensor"`` (read from the rig's BME280), ``"given"`` (``--ambient`` or ``rig.toml
    [ambient]``) or ``"none"`` (nothing: the run is *uncorrected*, its map stays at the J1349 reference
    day and the air term widens to a plausible day, :func:`uncorrected_air_rel_u`).
    ``pressure_kpa`` is station pressure, as a barometer or a BME280 reads it.
    """

    temp_c: float | None = None
    pressure_kpa: float | None = None
    rh_pct: float | None = None
    source: str = "none"

    @property
    def corrected(self) -> bool:
        return self.source != "none" and self.temp_c is not None and self.pressure_kpa is not None

    @property
    def dry_pressure_kpa(self) -> float | None:
        if not self.corrected:
            return None
        return dry_air_pressure_kpa(self.pressure_kpa, self.temp_c,
                                    RH_UNKNOWN_PCT if self.rh_pct is None else self.rh_pct)

    @property
    def j1349_factor(self) -> float | None:
        return j1349_correction_factor(self.temp_c, self.dry_pressure_kpa) if self.corrected else None

    def air_rel_u(self, altitude_m: float | None = None) -> float:
        """Relative standard uncertainty the air leaves in efficiency (see the two functions above);
        ``altitude_m``: the site's (``rig.toml [ambient]``), narrowing an uncorrected run's pressure range."""
        if not self.corrected:
            return uncorrected_air_rel_u(altitude_m)
        return known_air_rel_u(self.temp_c, self.pressure_kpa, self.rh_pct)

    def to_dict(self) -> dict:
        """The run's ``ambient`` (meta.json, the run's JSON): the one place the library and report read."""
        return {"temp_c": self.temp_c, "pressure_kpa": self.pressure_kpa, "rh_pct": self.rh_pct,
                "source": self.source, "j1349_factor": self.j1349_factor}

    @classmethod
    def from_dict(cls, d) -> "Ambient":
        if not isinstance(d, dict):
            return cls()
        return cls(d.get("temp_c"), d.get("pressure_kpa"), d.get("rh_pct"), d.get("source") or "none")


def parse_ambient(text: str, what: str = "--ambient", source: str = "given") -> Ambient:
    """``TEMP_C,PRESSURE_KPA[,RH_PCT]`` (station pressure) -> :class:`Ambient`; ValueError names what is wrong."""
    parts = [s.strip() for s in str(text).split(",")]
    try:
        vals = [float(s) for s in parts]
    except ValueError:
        vals = []
    if len(vals) not in (2, 3) or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{what}: expected TEMP_C,PRESSURE_KPA[,RH_PCT] (e.g. 35,90,20), got {text!r}")
    t, p = vals[0], vals[1]
    rh = vals[2] if len(vals) == 3 else None
    check_air(t, p, rh, what)
    return Ambient(t, p, rh, source)


def check_air(temp_c, pressure_kpa, rh_pct, what: str) -> None:
    """A day a dyno can be run on: −40…60 °C, 50…110 kPa station pressure, 0…100 %RH."""
    if not -40.0 <= temp_c <= 60.0:
        raise ValueError(f"{what}: TEMP_C {temp_c:g} is not an intake air temperature (-40..60 C)")
    if not 50.0 <= pressure_kpa <= 110.0:
        raise ValueError(f"{what}: PRESSURE_KPA {pressure_kpa:g} is not a station pressure in kPa (50..110; "
                         "hPa/mbar divide by 10)")
    if rh_pct is not None and not 0.0 <= rh_pct <= 100.0:
        raise ValueError(f"{what}: RH_PCT {rh_pct:g} is not a relative humidity (0..100 %)")
