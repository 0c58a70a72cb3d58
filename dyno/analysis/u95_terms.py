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


def term(name: str, u_rel, basis: str) -> dict:
    return {"term": name, "u_rel": None if u_rel is None else float(u_rel), "basis": basis}


def base_terms(calibration_rel: float, entries: int, engine_map_rel: float, map_basis: str) -> list[dict]:
    """The terms known before the run starts (the air is added when the day is read: :func:`air_term`)."""
    return [term("statistical", None, "each point's efficiency_ci95: the scatter of its measuring window"),
            term("calibration", calibration_rel,
                 f"the torque calibration history's slope reproducibility ({entries} entries, relative sd, with "
                 "the latest fit's slope error), and per point the tare's"),
            term("engine_map", engine_map_rel, map_basis)]


def map_basis(engine_map, rig_default: float) -> tuple[float, str]:
    """The map term's value and basis: the map file's statement, else the rig file's default."""
    stated = getattr(engine_map, "stated_u_rel", None)
    if stated is None:
        return rig_default, ("rig.toml [uncertainty] engine_map_rel: the map file states no uncertainty "
                             "(no '# stated_u_rel' line)")
    why = getattr(engine_map, "stated_u_basis", "") or "no basis given"
    return stated, f"stated in the map file ({getattr(engine_map, 'source', '?')}): {why}"


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
