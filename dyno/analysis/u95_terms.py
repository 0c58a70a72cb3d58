"""What each term of a point's ``efficiency_u95`` assumes: its value and where the value comes from (pure).

A run states these once (``meta.json`` ``uncertainty.u95_terms``, the run's JSON ``u95_terms``, the report's
"Uncertainty" section), so a reader can see which figures are measured and which are taken on trust:

* ``statistical``: each point's own ``efficiency_ci95`` (the window's scatter; per point, no assumption);
* ``calibration``: the torque calibration's slope reproducibility, the relative standard deviation of the
  history's slopes (with the latest fit's own slope error) and, per point, the tare's;
* ``engine_map``: the map's torque, its relative standard uncertainty as the map file states it
  (``# stated_u_rel = …`` in the CSV, :func:`dyno.analysis.engine_map.load_engine_map`), else ``rig.toml
  [uncertainty] engine_map_rel`` (5 % unless set) for a map that states none;
* ``driveline``: the one-sided bound of a loss between the CVT and the gauge (``rig.toml [driveline]``);
* ``air``: the SAE J1349 factor, what the day's air is known to (sensor, given) or a bound over a plausible
  day when none is known (:mod:`dyno.analysis.air`);
* with the engine-side input torque channel, ``calibration_input`` and ``cradle`` (``engine_map`` and
  ``air`` then do not enter: the engine is measured).

``u_rel`` is a relative *standard* uncertainty (the 95 % half-width is about twice it times the efficiency).
"""

from __future__ import annotations

import math


def term(name: str, u_rel, basis: str) -> dict:
    return {"term": name, "u_rel": None if u_rel is None else float(u_rel), "basis": basis}


def base_terms(calibration_rel: float, entries: int, engine_map_rel: float, map_basis: str,
               map_measured: bool = False) -> list[dict]:
    """The terms known before the run starts (the air is added when the day is read: :func:`air_term`); the
    map's says whether the map is measured on this engine (``measured``)."""
    return [term("statistical", None, "each point's efficiency_ci95: the scatter of its measuring window"),
            term("calibration", calibration_rel,
                 f"the torque calibration history's slope reproducibility ({entries} entries, relative sd, with "
                 "the latest fit's slope error), and per point the tare's"),
            {**term("engine_map", engine_map_rel, map_basis), "measured": bool(map_measured)}]


#: The evidence on how far an engine of the class sits from a map *not measured on it* (docs/analysis.md):
#: the 2019 thesis rig's engine made 4-14 % less than its own map on a standard day, about -9 %
#: (its real logs: the apparent map-based efficiency 0.79-0.82 over a CVT at 0.94-0.96, the day's J1349 factor
#: 1.03-1.10), and a used 10 hp Baja engine's chart in the thesis sits 3.9 % RMS from its map's shape.
ENGINE_2019_VS_MAP_REL = -0.09
USED_ENGINE_SHAPE_RMS_REL = 0.039
#: One engine is one draw from the class's spread about a representative map, so its deviation is the spread's
#: scale; the shape's scatter adds in quadrature:  u = sqrt(0.09^2 + 0.039^2) = 0.098.  A map not measured on
#: the rig's engine (``# measured_on_this_engine = no``, or not said) never states less.
UNMEASURED_MAP_U_REL = math.hypot(ENGINE_2019_VS_MAP_REL, USED_ENGINE_SHAPE_RMS_REL)
#: A map is a new engine's (or a class's); an engine in service only loses power to it (ring and valve wear,
#: carbon, a loaded filter), so a map not measured on this engine also carries a one-sided term: the engine up
#: to this much weaker, uniform (:mod:`dyno.analysis.systematic`).  The far end of the one real engine's range.
ENGINE_WEAR_MAX_FRAC = 0.14

MEASURE_THE_ENGINE = ("the engine map is not measured on this engine, and its term dominates: measure the engine "
                      "(the input torque channel, hardware/rig-input-torque.toml; or a map from `dyno replay "
                      "--measured-map`) for an interval a few pp wide")


def map_basis(engine_map, rig_default: float) -> tuple[float, str]:
    """The map term's value and basis: the map file's statement, else the rig file's default; for a map not
    measured on this engine, at least :data:`UNMEASURED_MAP_U_REL` (the evidence of real engines against maps)."""
    stated = getattr(engine_map, "stated_u_rel", None)
    if stated is None:
        value, basis = rig_default, ("rig.toml [uncertainty] engine_map_rel: the map file states no uncertainty "
                                     "(no '# stated_u_rel' line)")
    else:
        why = getattr(engine_map, "stated_u_basis", "") or "no basis given"
        value, basis = stated, f"stated in the map file ({getattr(engine_map, 'source', '?')}): {why}"
    if map_measured(engine_map) or value >= UNMEASURED_MAP_U_REL:
        return value, basis
    return UNMEASURED_MAP_U_REL, (f"{basis}; raised from {100 * value:g} % to {100 * UNMEASURED_MAP_U_REL:.1f} %: the "
                                  "map is not measured on this engine, and real engines sit that far from maps "
                                  "(the 2019 rig's ran ~9 % under its own; docs/analysis.md)")


def map_measured(engine_map) -> bool:
    """Whether the map file says it was measured on this rig's engine (``# measured_on_this_engine = yes``)."""
    return getattr(engine_map, "measured_on_this_engine", None) is True


def advice(terms, points) -> str:
    """What narrows the run's intervals, when something obvious does: '' otherwise."""
    found = largest_term(points)
    emap = next((t for t in terms or [] if t.get("term") == "engine_map"), None)
    if found and found[0] in ("engine_map", "engine_wear") and emap is not None and emap.get("measured") is False:
        return MEASURE_THE_ENGINE
    return ""


def engine_wear_term(wear_max_frac: float) -> dict:
    """The engine's wear for a map not measured on this engine: one-sided (a worn engine only makes less)."""
    return term("engine_wear", None, f"one-sided: the map is not measured on this engine, and an engine in "
                f"service only loses power to its map (wear, carbon, filter): up to {100 * wear_max_frac:g} % weaker "
                "(the 2019 rig's engine: 4-14 % under its own), so the truth may lie above the reading")


def air_term(air_rel: float, source: str | None) -> dict:
    if source in ("sensor", "given"):
        basis = (f"the day's air as {'the BME280 read it' if source == 'sensor' else 'given'}: ±1 °C, ±1 hPa, "
                 "±3 %RH (rectangular) through the SAE J1349 factor")
    else:
        basis = ("no air known: the J1349 factor's spread over a plausible day (dyno.analysis.air; narrowed by "
                 "rig.toml [ambient] altitude_m when set)")
    return term("air", air_rel, basis)


def driveline_term(loss_max_frac: float, drag_max_nm: float) -> dict:
    """The driveline between the CVT and the gauge: one-sided (a loss only lowers the reading), per point."""
    return term("driveline", None, f"one-sided, rig.toml [driveline]: up to {100 * loss_max_frac:g} % of the load "
                f"(chain) plus {drag_max_nm:g} N m of bearing drag over each point's torque; a loss only lowers the "
                "reading")


def input_terms(channel) -> list[dict]:
    """The input torque channel's terms (the map and the air then do not enter)."""
    return [term("calibration_input", channel.calibration_rel,
                 f"the input channel's calibration history ({channel.source}): slope reproducibility, and per "
                 "point the tare's"),
            term("cradle", None, f"the cradle bearings' loss known to ±{channel.bearing_loss_u_nm:g} N m "
                 "(rig.toml [input_torque] bearing_loss_u_nm), relative to each point's input torque")]


def describe(terms) -> list[str]:
    """One line per term, for the report and the terminal."""
    out = []
    for t in terms or []:
        u = t.get("u_rel")
        fig = "per point" if u is None else f"{100 * u:.2f} % (standard, relative)"
        out.append(f"{t.get('term')}: {fig} — {t.get('basis')}")
    return out


#: what ``dyno compare`` does with the terms two runs share (dyno.library.compare_terms), for the readers
COMPARE_NOTE = ("`dyno compare` cancels what two runs share (the same calibration entry, the same engine map at "
                "one engine speed, the air each run was corrected to): a change between runs is known better than "
                "either run's U95")

COMPARE_NOTE_SHORT = "`dyno compare` cancels what runs share"
#: the terms' names in a 30-column screen field
TERM_SHORT = {"statistical": "scatter", "calibration": "calib.", "engine_map": "map", "engine_wear": "wear",
              "calibration_input": "calib.in",
              "driveline": "driveline", "air": "air", "cradle": "cradle", "friction": "friction"}


def largest_term(points) -> tuple[str, float, float] | None:
    """The term of ``efficiency_u95`` that dominates the points: (name, its 95 % half-width, the U95), each the
    root mean square over the points that state their terms (``efficiency_u95_terms``); None without any."""
    sums: dict[str, float] = {}
    u95_sq, n = 0.0, 0
    for p in points or []:
        terms, u95 = p.get("efficiency_u95_terms"), p.get("efficiency_u95")
        if not isinstance(terms, dict) or not isinstance(u95, float) or not math.isfinite(u95):
            continue
        n += 1
        u95_sq += u95 * u95
        for name, v in terms.items():
            if isinstance(v, (int, float)) and math.isfinite(v):
                sums[name] = sums.get(name, 0.0) + float(v) * float(v)
    if not n or not sums:
        return None
    name = max(sums, key=sums.get)
    return name, math.sqrt(sums[name] / n), math.sqrt(u95_sq / n)


def largest_term_text(points, *, short: bool = False) -> str:
    """``largest U95 term: engine_map (±4.1 pp of ±4.6 pp)`` (``short``: ``engine_map ±4.1/4.6 pp``); '' without."""
    found = largest_term(points)
    if found is None:
        return ""
    name, half, u95 = found
    if short:
        return f"{name} ±{100 * half:.1f}/{100 * u95:.1f} pp"
    return f"largest U95 term: {name} (±{100 * half:.1f} pp of ±{100 * u95:.1f} pp, rms over the points)"
