"""The engine's measured torque curve from the input torque channel, against its map (issue 27; pure).

A run whose points carry ``torque_input_nm`` (``efficiency_source == "input_torque"``) has measured what
its engine makes at each point's speed.  The full-throttle points, grouped by engine speed, give a measured
curve with a 95 % half-width per speed: the calibration part of it (slope reproducibility, tare, cradle
bearings) is shared by every point, so averaging shrinks only the statistical part.  Against the map the
host was given it reads "at 3,000 rpm your engine makes 4 % less than its map".  :func:`write_map` saves it
in the engine-map format (``rpm,torque_nm``; each row's uncertainty in its comments and the map's relative
standard uncertainty as its ``# stated_u_rel`` line), which ``--engine-map`` then reads: a run on it states
the measurement's uncertainty for its map term (:mod:`dyno.analysis.u95_terms`).
"""

from __future__ import annotations

import math
import statistics

BIN_RPM = 100.0  # points closer than this in engine speed are one speed of the curve


def measured_curve(points, engine_map=None, *, bin_rpm: float = BIN_RPM) -> list[dict]:
    """``[{rpm, torque_nm, torque_u95_nm, n_points, map_torque_nm, vs_map_rel, vs_map_u95_rel}]`` by speed."""
    rows = []
    for p in points:
        t, u = p.get("torque_input_nm"), p.get("torque_input_u95_nm")
        rpm = p.get("rpm_primary")
        if (p.get("efficiency_source") != "input_torque" or p.get("throttle_frac", 1.0) < 1.0 or not p.get("valid", True)
                or not all(isinstance(x, float) and math.isfinite(x) for x in (t or math.nan, u or math.nan,
                                                                                rpm or math.nan))):
            continue
        sem = p.get("torque_input_sem_nm")
        stat = 2.0 * sem if isinstance(sem, float) and math.isfinite(sem) else 0.0
        rows.append((rpm, t, math.sqrt(max(0.0, u * u - stat * stat)), stat))
    rows.sort()
    bins: list[list] = []
    for r in rows:
        if bins and r[0] - bins[-1][0][0] <= bin_rpm:
            bins[-1].append(r)
        else:
            bins.append([r])
    out = []
    for b in bins:
        n = len(b)
        rpm = statistics.fmean(r[0] for r in b)
        torque = statistics.fmean(r[1] for r in b)
        sys95 = statistics.fmean(r[2] for r in b)           # common to the points: not averaged down
        stat95 = math.sqrt(sum(r[3] ** 2 for r in b)) / n  # independent: averaged down
        u95 = math.hypot(sys95, stat95)
        row = {"rpm": rpm, "torque_nm": torque, "torque_u95_nm": u95, "n_points": n}
        if engine_map is not None:
            try:
                m = float(engine_map.torque_nm(rpm))
            except Exception:  # outside the map's range: no comparison at this speed
                m = math.nan
            row.update(map_torque_nm=m, vs_map_rel=torque / m - 1.0 if m > 0 else math.nan,
                       vs_map_u95_rel=u95 / m if m > 0 else math.nan)
        out.append(row)
    return out


def describe(curve: list[dict]) -> list[str]:
    """One sentence per speed: what the engine makes against its map."""
    lines = []
    for r in curve:
        rel = r.get("vs_map_rel")
        if rel is None or not math.isfinite(rel):
            lines.append(f"at {r['rpm']:,.0f} rpm your engine makes {r['torque_nm']:.2f} ± {r['torque_u95_nm']:.2f} N m")
            continue
        word = "less" if rel < 0 else "more"
        lines.append(f"at {r['rpm']:,.0f} rpm your engine makes {100 * abs(rel):.1f} % {word} than its map "
                     f"(± {100 * r['vs_map_u95_rel']:.1f} %, 95 %): {r['torque_nm']:.2f} ± {r['torque_u95_nm']:.2f} "
                     f"N m against {r['map_torque_nm']:.2f}")
    return lines


def write_map(curve: list[dict], path, *, source: str = "") -> str:
    """The measured curve as an engine-map CSV (``rpm,torque_nm``); returns its text."""
    from pathlib import Path

    if len(curve) < 2:
        raise ValueError("a map needs the engine measured at two speeds at least (full-throttle points "
                         "with the input torque channel)")
    u_rel = max(r["torque_u95_nm"] / 2.0 / r["torque_nm"] for r in curve)
    lines = ["# MEASURED engine map: full-throttle net torque from the engine-side input torque channel",
             f"# (dyno, issue 27){' from ' + source if source else ''}; between and beyond these speeds the map "
             "interpolates / refuses as any map.",
             f"# stated_u_rel = {math.ceil(u_rel * 1000) / 1000:.3f} | measured through the input torque channel: "
             f"the largest row's relative standard uncertainty ({u_rel:.4f}; calibration, tare, cradle, scatter)",
             "# measured_on_this_engine = yes | the rig's engine, through its input torque channel",
             "# per row: rpm, torque_nm, its 95 % half-width (N m), points: "
             + "; ".join(f"{r['rpm']:.0f} {r['torque_nm']:.3f} ±{r['torque_u95_nm']:.3f} ({r['n_points']})"
                         for r in curve),
             "rpm,torque_nm"]
    lines += [f"{r['rpm']:.1f},{r['torque_nm']:.4f}" for r in curve]
    text = "\n".join(lines) + "\n"
    Path(path).write_text(text)
    return text
