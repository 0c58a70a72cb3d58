"""One run as a self-contained HTML page: pure (a :class:`ReportData` in, an HTML string out).

Figures are SVG embedded as ``data:`` URIs (nothing to fetch, each figure's ids kept to itself); the numbers
they plot are also in a ``<script type="application/json" id="dyno-report-data">`` block, so the page can be
checked or re-plotted by a program.  Efficiency is a fraction in that block (as in every machine file) and
in % wherever a person reads it.
"""

from __future__ import annotations

import base64
import datetime as _dt
import json
import math
from dataclasses import dataclass, field
from html import escape

from dyno.report import figures, sections

CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 70em; color: #222; }
h1 { font-size: 1.4em; } h2 { font-size: 1.15em; border-bottom: 1px solid #ccc; margin-top: 1.6em; }
table { border-collapse: collapse; font-size: 0.85em; } td, th { padding: 0.15em 0.6em; text-align: right; }
th { background: #eee; } tr:nth-child(even) td { background: #f7f7f7; } td.l, th.l { text-align: left; }
.bad { color: #b00; font-weight: bold; } .ok { color: #070; font-weight: bold; } .warn { color: #a60; }
pre { background: #f4f4f4; padding: 0.6em; font-size: 0.8em; overflow-x: auto; }
img.fig { max-width: 100%; display: block; margin: 0.5em 0; }
"""


@dataclass
class ReportData:
    """Everything the page shows, already read from the run directory (see :mod:`dyno.report.writer`)."""

    run_dir: str
    meta: dict
    documents: list
    calibration: dict | None = None
    engine_map: dict | None = None       # rpm, torque_nm, power_w (sampled), source, sha256, j1349_factor, notes
    tune_text: str | None = None
    model: dict | None = None            # rpm_secondary, efficiency (fractions), label
    predicted_shift: dict | None = None  # engine_rpm, ratio
    advised: dict | None = None          # dyno tune advise's prediction for this tune (dyno.library.advice)
    generator_version: str = ""
    generated_unix_s: float = 0.0
    notes: list = field(default_factory=list)  # optional parts that could not be made, with why

    def docs(self, doc_type: str) -> list:
        return [d for d in self.documents if d.get("type") == doc_type]


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def exclusion_reason(p: dict) -> str | None:
    """Why a point is left out of the curves (None: it is plotted)."""
    if p.get("discarded"):
        return "discarded (taken before loading)" if p.get("legacy_point") == 0 else "discarded"
    if p.get("valid") is False:
        why = "; ".join(f.get("reason", "") for f in p.get("faults", []) if isinstance(f, dict))
        return f"invalid{': ' + why if why else ''}"
    for key in ("rpm_primary", "rpm_secondary", "torque_secondary_nm", "efficiency"):
        if not _finite(p.get(key)):
            why = p.get("efficiency_reason") if key == "efficiency" else None  # e.g. no curve at its throttle
            return f"no {key.replace('_', ' ')}{': ' + why if why else ''}"
    if not 0.0 <= p["efficiency"] <= 1.0:
        return f"implausible efficiency {100 * p['efficiency']:.1f} % (outside 0..100 %)"
    return None


def plot_series(data: ReportData) -> dict:
    """The numbers every figure plots (JSON-ready: NaN becomes None)."""
    keys = ("index", "rpm_primary", "rpm_secondary", "ratio", "torque_secondary_nm", "power_out_w", "power_in_w",
            "efficiency", "efficiency_sem")
    pts = {k: [] for k in keys}
    excl = {"index": [], "rpm_secondary": [], "efficiency": [], "reason": []}
    truth = {"rpm_secondary": [], "efficiency": []}
    for i, p in enumerate(data.docs("point")):
        why = exclusion_reason(p)
        if why:
            if _finite(p.get("rpm_secondary")) and _finite(p.get("efficiency")):
                excl["index"].append(p.get("index", i))
                excl["rpm_secondary"].append(p["rpm_secondary"])
                excl["efficiency"].append(p["efficiency"])
                excl["reason"].append(why)
            continue
        for k in keys:
            v = p.get(k, i if k == "index" else None)
            if k == "efficiency_sem" and not _finite(v):
                v = 0.0  # no spread known: drawn without a bar
            pts[k].append(v if (k == "index" or _finite(v)) else None)
        if _finite(p.get("efficiency_true")):
            truth["rpm_secondary"].append(p["rpm_secondary"])
            truth["efficiency"].append(p["efficiency_true"])
    return {"efficiency": {"points": pts, "excluded": excl, "model": data.model,
                           "truth": truth if truth["efficiency"] else None},
            "shift": {"points": pts, "predicted": data.predicted_shift},
            "torque_power": {"points": pts},
            "engine_map": data.engine_map}


# --- HTML pieces ---------------------------------------------------------------------------------
def _img(svg: str, alt: str, fig_id: str) -> str:
    b64 = base64.b64encode(svg.encode("utf-8")).decode("ascii")
    return f'<img class="fig" id="{fig_id}" alt="{escape(alt)}" src="data:image/svg+xml;base64,{b64}">'


def _table(head: list[str] | None, rows: list[list], left=()) -> str:
    """An HTML table; ``left``: indices of the (text) columns aligned left."""
    def cell(tag, k, v):
        cls = ' class="l"' if k in left else ""
        return f"<{tag}{cls}>{v}</{tag}>"
    out = ["<table>"]
    if head:
        out.append("<tr>" + "".join(cell("th", k, escape(h)) for k, h in enumerate(head)) + "</tr>")
    for r in rows:
        out.append("<tr>" + "".join(cell("td", k, v) for k, v in enumerate(r)) + "</tr>")
    return "\n".join(out) + "</table>"


def _kv(rows: list[tuple[str, object]]) -> str:
    return _table(None, [[escape(k), escape(str(v))] for k, v in rows], left={0, 1})


def _f(v, spec: str, scale: float = 1.0) -> str:
    return format(v * scale, spec) if _finite(v) else "—"


def _when(unix_s) -> str:
    if not _finite(unix_s):
        return "unknown"
    return _dt.datetime.fromtimestamp(unix_s, _dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def _summary(data: ReportData) -> str:
    stop = (data.docs("stop") or [{}])[-1]
    status = stop.get("exit_status", "no stop record (the run was killed, or is still running)")
    points = data.docs("point")
    plotted = [p for p in points if exclusion_reason(p) is None]
    cls = "ok" if status == "success" else "bad"
    rows = [("run directory", data.run_dir), ("mode", data.meta.get("mode", "?")),
            ("started", _when(data.meta.get("created_unix_s"))),
            ("points", f"{len(points)} recorded, {len(plotted)} plotted, {len(points) - len(plotted)} left out"),
            ("aborts", len(data.docs("abort"))), ("re-measured windows", len(data.docs("discard"))),
            ("skipped windows", len(data.docs("skip")))]
    if plotted:
        eff = [p["efficiency"] for p in plotted]
        best = max(plotted, key=lambda p: p.get("power_out_w") or 0.0)
        rows += [("efficiency", f"{100 * min(eff):.1f} … {100 * max(eff):.1f} %"),
                 ("peak output power", f"{_f(best.get('power_out_w'), '.2f', 1e-3)} kW at "
                                       f"{_f(best.get('rpm_secondary'), '.0f')} secondary rpm")]
    link = stop.get("link") or {}
    if link:
        rows.append(("link", f"{link.get('read', '?')} frames read, {link.get('accepted', '?')} accepted, "
                             f"{link.get('rejected_total', 0)} rejected, {link.get('events_lost', 0)} events lost"))
    sup = stop.get("supervisor") or {}
    if sup.get("armed_by_host"):
        drops = sup.get("drops") or []
        rows.append(("Nano run-enable", ("present: " if sup.get("present") else "absent: ") +
                     (f"{len(drops)} drop(s), last: {drops[-1]['cause']}" if drops else "never dropped")))
    head = (f'<p>Status: <span class="{cls}">{escape(str(status))}</span>'
            f'{" — " + escape(str(stop["reason"])) if stop.get("reason") else ""}</p>')
    return head + _kv(rows)


def _points_table(data: ReportData) -> str:
    rows = []
    # the engine-side input torque channel (issue 27): its torque, and the map's figure beside the measured one
    has_input = any(p.get("efficiency_source") == "input_torque" for p in data.docs("point"))
    for i, p in enumerate(data.docs("point")):
        why = exclusion_reason(p)
        notes = [f.get("reason", "") for f in (p.get("faults") or []) + (p.get("legacy_faults") or [])
                 if isinstance(f, dict) and f.get("reason")]
        state = '<span class="ok">plotted</span>' if why is None else f'<span class="bad">{escape(why)}</span>'
        rows.append([p.get("index", i), _f(p.get("rpm_primary"), ".0f"), _f(p.get("rpm_secondary"), ".0f"),
                     _f(p.get("ratio"), ".3f"), _f(p.get("torque_secondary_nm"), ".2f"),
                     _f(p.get("power_out_w"), ".2f", 1e-3), _f(p.get("power_in_w"), ".2f", 1e-3),
                     _f(p.get("efficiency"), ".1f", 100), _f(p.get("efficiency_ci95"), ".1f", 100),
                     _f(p.get("efficiency_sys95"), ".1f", 100), _f(p.get("efficiency_u95"), ".1f", 100),
                     _interval(p.get("efficiency_interval95")),
                     state + "".join(f'<br><span class="warn">{escape(n)}</span>' for n in notes)])
        if has_input:
            rows[-1][5:5] = [_f(p.get("torque_input_nm"), ".2f")]
            rows[-1][-1:-1] = [_f(p.get("efficiency_engine_map"), ".1f", 100),
                               _f(p.get("efficiency_engine_map_u95"), ".1f", 100),
                               _interval(p.get("efficiency_engine_map_interval95"))]
    if not rows:
        return "<p>No points were recorded.</p>"
    head = ["#", "engine rpm", "secondary rpm", "ratio", "torque N·m", "P out kW", "P in kW",
            "efficiency %", "CI95 ± pp (the point's statistics)", "systematic ± pp (half their interval's width)",
            "U95 ± pp (half of interval95's width)", "interval95 % (the truth at 95 %)", "state / notes"]
    if has_input:  # P in and the efficiency from the measured input torque; the map's figure beside
        head[5:5] = ["engine torque N·m (measured)"]
        head[-1:-1] = ["efficiency % (engine map)", "U95 ± pp (map, half its interval95)", "interval95 % (map)"]
        return ("<p>Efficiency from the engine-side input torque channel: P out / (T in · ω p); the engine "
                "map's figure beside it for comparison.</p>" + _table(head, rows, left={16}))
    return _table(head, rows, left={12})


def _interval(iv) -> str:
    """``[low, high]`` (fractions) as ``low…high`` in %; "–" without one."""
    if not isinstance(iv, (list, tuple)) or len(iv) != 2 or not all(isinstance(v, (int, float)) for v in iv):
        return "–"
    return f"{100 * iv[0]:.1f}…{100 * iv[1]:.1f}"


def _faults(data: ReportData) -> str:
    parts = []
    if data.docs("abort"):
        parts.append("<h3>Aborts</h3>" + _table(
            ["cause", "detail", "state", "safe-state latency ms"],
            [[escape(str(a.get("cause"))), escape(str(a.get("detail"))), escape(str(a.get("state"))),
              _f(a.get("latency_s"), ".1f", 1e3)] for a in data.docs("abort")], left={0, 1, 2}))
    if data.docs("discard"):
        parts.append("<h3>Windows measured again (disturbed)</h3>" + _table(
            ["point", "attempt", "reason"],
            [[d.get("index"), d.get("attempt"), escape(str(d.get("reason")))] for d in data.docs("discard")],
            left={2}))
    if data.docs("skip"):
        parts.append("<h3>Windows skipped</h3><ul>" + "".join(
            f"<li>{escape(str(s.get('reason')))}</li>" for s in data.docs("skip")) + "</ul>")
    left_out = [(p.get("index", i), exclusion_reason(p)) for i, p in enumerate(data.docs("point"))]
    left_out = [(k, why) for k, why in left_out if why]
    if left_out:
        parts.append("<h3>Points left out of the curves</h3><ul>" + "".join(
            f"<li>point {k}: {escape(why)}</li>" for k, why in left_out) + "</ul>")
    for doc in data.docs("faults"):
        parts.append("<h3>Import faults</h3>" + _table(
            ["point", "channel", "severity", "reason"],
            [[f.get("point", ""), escape(str(f.get("channel", ""))), escape(str(f.get("severity", ""))),
              escape(str(f.get("reason", "")))] for f in doc.get("faults", [])], left={1, 2, 3}))
    return "\n".join(parts) or "<p>No aborts, faults or discarded points.</p>"


def _calibration(data: ReportData) -> str:
    c = data.calibration
    if not c:
        return "<p>No calibration stored with this run.</p>"
    rows = [("source", data.meta.get("calibration_source", "?")), ("date", c.get("date")),
            ("slope", f"{_f(c.get('slope_counts_per_nm'), '.3f')} counts per N·m"),
            ("intercept", f"{_f(c.get('intercept_counts'), '.1f')} counts"), ("R²", _f(c.get("r2"), ".6f")),
            ("gear ratio brake / secondary", _f(c.get("gear_ratio_brake_per_secondary"), ".4f")),
            ("lever arm", _f(c.get("lever_arm_m"), ".4f") + (" m" if _finite(c.get("lever_arm_m")) else "")),
            ("note", c.get("note", ""))]
    return _kv(rows)


def air_text(amb) -> str:
    """The run's air and what was done with it, in words (meta.json ``ambient``, dyno.session.ambient)."""
    if not isinstance(amb, dict) or not amb:
        return ("not recorded (a run from before the air was logged): the map is used as recorded, at the "
                "SAE J1349 reference day")
    if amb.get("j1349_factor") is None:
        return ("uncorrected: no air was known (no BME280, no --ambient, no rig.toml [ambient] day), so the map "
                "stays at the SAE J1349 reference day (25 °C, 99 kPa dry) and each point's efficiency_interval95 "
                "carries the factor's range over a plausible day (−10…45 °C, 80…105 kPa, or the site's "
                "[ambient] altitude_m): asymmetric, the truth up to ~30 % above the figure, ~10 % below")
    rh = amb.get("rh_pct")
    rh_s = f", {rh:.0f} %RH" if isinstance(rh, (int, float)) else ", humidity not given"
    src = {"sensor": "read from the rig's BME280", "given": "given (--ambient or rig.toml)"}.get(amb.get("source"),
                                                                                                  str(amb.get("source")))
    end = amb.get("end") if isinstance(amb.get("end"), dict) else None
    end_s = (f"; after the run {end['temp_c']:.1f} °C, {end['pressure_kpa']:.2f} kPa"
             if end and isinstance(end.get("temp_c"), (int, float)) else "")
    return (f"SAE J1349 factor {amb['j1349_factor']:.4f}: the engine made 1/{amb['j1349_factor']:.4f} of its "
            f"standard-day map on a day of {amb['temp_c']:.1f} °C, {amb['pressure_kpa']:.2f} kPa station pressure"
            f"{rh_s} ({src}){end_s}")


def _engine_map(data: ReportData) -> str:
    m = data.engine_map
    if not m:
        return "<p>No engine map stored with this run: no input power, no efficiency.</p>"
    atmos = air_text(data.meta.get("ambient"))
    rows = [("source", data.meta.get("engine_map_source") or m.get("source") or "?"),
            ("sha256", data.meta.get("engine_map_sha256") or m.get("sha256") or "?"),
            ("speed range", f"{_f(m['rpm'][0], '.0f')} … {_f(m['rpm'][-1], '.0f')} rpm"),
            ("atmospheric correction", atmos)]
    notes = "".join(f"<li>{escape(n)}</li>" for n in m.get("notes", []))
    return (_kv(rows) + (f"<ul>{notes}</ul>" if notes else "")
            + _img(figures.engine_map_svg(m), "engine map: torque and power vs engine speed", "fig-engine-map"))


def _u95_terms(data: ReportData) -> str:
    """What each term of the points' efficiency_u95 assumes (meta.json uncertainty.u95_terms)."""
    from dyno.analysis.u95_terms import describe

    from dyno.analysis.u95_terms import COMPARE_NOTE, advice, largest_term_text

    terms = (data.meta.get("uncertainty") or {}).get("u95_terms")
    if not terms:
        return ""
    items = "".join(f"<li>{escape(line)}</li>" for line in describe(terms))
    largest = largest_term_text(data.docs("point"))
    lead = f'<p id="u95-largest"><b>{escape(largest)}</b>.</p>' if largest else ""
    return (f'<h2 id="u95-terms">What efficiency_u95 assumes</h2>{lead}<ul>{items}</ul>'
            f'<p id="u95-compare">{escape(COMPARE_NOTE)}.</p>'
            + (f'<p id="u95-advice"><b>To narrow:</b> {escape(hint)}.</p>'
               if (hint := advice(terms, data.docs("point"))) else ""))


def _tune(data: ReportData) -> str:
    if not data.tune_text:
        return "<p>No CVT tune stored with this run.</p>"
    src = data.meta.get("tune_source", "?")
    return f"<p>source: {escape(str(src))} (sha256 {escape(str(data.meta.get('tune_sha256', '?')))})</p>" \
           f"<pre>{escape(data.tune_text)}</pre>"


def _versions(data: ReportData) -> str:
    m = data.meta
    fw = m.get("firmware_version") or m.get("firmware") or (
        "emulated v1 firmware (simulated rig)" if m.get("mode") == "sim" else "not recorded in this run")
    rows = [("software that recorded the run", m.get("software_version", "?")), ("run format", m.get("format", "?")),
            ("protocol", m.get("protocol", "?")), ("firmware", fw), ("seed", m.get("seed", "—")),
            ("rig description", m.get("rig_config", "—")),
            ("report made by", f"dyno {data.generator_version} at {_when(data.generated_unix_s)}")]
    if m.get("legacy_source"):
        rows.insert(0, ("imported from", m["legacy_source"]))
    return _kv(rows)


def _json_block(series: dict) -> str:
    def clean(x):
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        return x
    text = json.dumps(clean(series), allow_nan=False, default=float).replace("</", "<\\/")
    return f'<script type="application/json" id="dyno-report-data">{text}</script>'


def render_report(data: ReportData) -> str:
    """The whole page."""
    series = plot_series(data)
    name = data.run_dir.rstrip("/").split("/")[-1] or data.run_dir
    model_note = ""
    if data.model:
        model_note = f"<p>Belt model: {escape(data.model.get('label', ''))}.</p>"
    notes = "".join(f'<li class="warn">{escape(n)}</li>' for n in data.notes)
    # a characterisation (engagement, coast-down) has no steady points: its own section, not empty plots
    characterisation_only = bool(data.docs("characterisation")) and not data.docs("point")
    body = [
        f"<h1>dyno run report: {escape(name)}</h1>",
        "<h2>Summary</h2>", _summary(data),
        f"<ul>{notes}</ul>" if notes else "",
        ("<h2>Characterisation</h2>" + sections.characterisation(data.docs("characterisation")))
        if data.docs("characterisation") else "",
        sections.advised(data.advised) if data.advised else "",
        ("<h2>Torque zero</h2>" + sections.torque_zero(data.docs("torque_zero"))) if data.docs("torque_zero") else "",
        ("<h3>Torque zero, input channel (crank N·m)</h3>" + sections.torque_zero(data.docs("torque_zero_input")))
        if data.docs("torque_zero_input") else "",
        ('<h2 id="drive-grid">Drive grid</h2>' + sections.drive_grid(data.docs("grid_cell"), data.docs("point")))
        if data.docs("grid_cell") else "",
        *([] if characterisation_only else [
            "<h2>Efficiency</h2>",
            _img(figures.efficiency_svg(series["efficiency"]), "efficiency vs secondary speed", "fig-efficiency"),
            model_note,
            "<h2>Shift curve</h2>",
            _img(figures.shift_svg(series["shift"]), "ratio vs engine speed", "fig-shift"),
            "<h2>Torque and power</h2>",
            _img(figures.torque_power_svg(series["torque_power"]), "torque and power vs secondary speed",
                 "fig-torque-power")]),
        "<h2>Points</h2>", _points_table(data),
        "<h2>Aborts, faults and discarded points</h2>", _faults(data),
        "<h2>Calibration</h2>", _calibration(data),
        "<h2>Engine map</h2>", _engine_map(data),
        _u95_terms(data),
        "<h2>CVT tune</h2>", _tune(data),
        "<h2>Versions</h2>", _versions(data),
        _json_block(series),
    ]
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>dyno report: {escape(name)}</title><style>{CSS}</style></head><body>\n"
            + "\n".join(b for b in body if b) + "\n</body></html>\n")
