"""SAE J1349 power correction and the air it needs (pure).  Used by the engine map
(:meth:`dyno.analysis.engine_map.EngineMap.at_ambient`), which re-exports these names."""

from __future__ import annotations

import math

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
