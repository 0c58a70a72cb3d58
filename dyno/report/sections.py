"""Report sections for the characterisation plans, the coast-down, the drive grid and the torque-zero check."""

from __future__ import annotations

import math
from html import escape


def _f(v, spec: str, scale: float = 1.0) -> str:
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    return format(v * scale, spec) if ok else "—"


def _table(head, rows) -> str:
    th = "".join(f"<th>{escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def ramp_svg(doc: dict) -> str:
    """Ratio vs engine speed over each throttle ramp, with the engagement and shift-out found."""
    from dyno.report.figures import new_figure, legend_or_note, render_styled, svg_text

    def draw() -> str:
        fig, (ax,) = new_figure()
        rows = [doc] + [r for r in (doc.get("shift_out_vs_load") or [])[1:]]
        for k, r in enumerate(rows):
            c = r.get("curve") or {}
            if not c.get("rpm_primary"):
                continue
            load = r.get("shift_out_torque_nm", r.get("torque_secondary_nm"))
            ax.plot(c["rpm_primary"], c["ratio"], "-", lw=1.0, color=f"C{k}",
                    label=f"ramp {k + 1} (load {_f(load, '.1f')} N·m)", gid=f"ramp-{k + 1}")
            for key, mark in (("engagement_rpm", "v"), ("shift_out_rpm", "o")):
                if isinstance(r.get(key), (int, float)) and math.isfinite(r[key]):
                    ax.axvline(r[key], color=f"C{k}", ls=":" if mark == "v" else "--", lw=0.8)
        ax.set(xlabel="engine speed, rpm", ylabel="ratio (engine / secondary speed)",
               title="throttle ramps: engagement (dotted), shift-out (dashed)")
        legend_or_note(ax)
        return svg_text(fig)

    return render_styled(draw)


def loss_svg(doc: dict) -> str:
    """The coast-down's loss torque vs secondary speed: the fit, its 95 % band, the sim's truth."""
    from dyno.report.figures import new_figure, legend_or_note, render_styled, svg_text

    def draw() -> str:
        fig, (ax,) = new_figure()
        f = doc["loss_fit"]
        r, t = f["rpm_grid"], f["torque_nm"]
        band = [math.hypot(a, b) for a, b in zip(f["torque_ci95_nm"], f["torque_sys95_nm"])]
        ax.fill_between(r, [x - b for x, b in zip(t, band)], [x + b for x, b in zip(t, band)], color="C0",
                        alpha=0.25, label="95 % (fit and inertia)")
        ax.plot(r, t, "-", color="C0", label="fitted a + bω + cω²", gid="loss-fit")
        if doc.get("loss_torque_true_nm"):
            ax.plot(r, doc["loss_torque_true_nm"], "--", color="C3", label="simulated truth", gid="loss-true")
        ax.set(xlabel="secondary speed, rpm", ylabel="loss torque at the secondary, N·m",
               title="driven-side loss from the coast-down")
        legend_or_note(ax)
        return svg_text(fig)

    return render_styled(draw)


def _embed(svg: str, fig_id: str, alt: str) -> str:
    import base64

    return (f'<img class="fig" id="{fig_id}" alt="{escape(alt)}" '
            f'src="data:image/svg+xml;base64,{base64.b64encode(svg.encode()).decode()}">')


def advised(a: dict) -> str:
    """The tune's advice (``dyno tune advise``) beside what this run measured, figure by figure."""
    rows = []
    for fig, r in a.get("figures", {}).items():
        err = r.get("error_rpm")
        rows.append([escape(fig), _f(r.get("predicted_rpm"), ".0f"), "± " + _f(r.get("u95_rpm"), ".0f"),
                     _f(r.get("measured_rpm"), ".0f"), "-" if err is None else f"{err:+.0f}"])
    src = escape(str(a.get("advice_file") or ""))
    return (f'<h2 id="advised">Advised</h2><p>This tune is one <code>dyno tune advise</code> proposed ({src}): '
            "its prediction beside this run's measurement.</p>"
            + _table(["figure", "predicted rpm", "U95", "measured rpm", "measured − predicted"], rows))


def characterisation(docs: list) -> str:
    """Engagement / shift-out / full-shift figures, or the coast-down's loss, with their 95 % intervals."""
    if not docs:
        return ""
    c = docs[-1]
    out = []
    if "engagement_rpm" in c:
        out.append(_embed(ramp_svg(c), "fig-ramps", "ratio vs engine speed over the throttle ramps"))
        rows = []
        pred = c.get("predicted") or {}
        for key, label, spec in (("engagement_rpm", "engagement (secondary starts to turn), engine rpm", ".0f"),
                                 ("lockup_rpm", "lock-up (belt stops slipping), engine rpm", ".0f"),
                                 ("shift_out_rpm", "shift-out (ratio leaves low gear), engine rpm", ".0f"),
                                 ("low_ratio", "low-gear speed ratio", ".4f"),
                                 ("full_shift_ratio", "full-shift speed ratio", ".4f")):
            rows.append([escape(label), _f(c.get(key), spec), "± " + _f(c.get(f"{key}_ci95"), spec),
                         _f(c.get(f"{key}_true"), spec), _f(pred.get(key), spec)])
        out.append(_table(["quantity", "measured", "95 %", "sim truth", "tune predicts"], rows))
        if pred.get("shift_out_rpm_full_load"):
            out.append(f"<p>The tune predicts a shift-out of {_f(pred['shift_out_rpm_full_load'], '.0f')} rpm at "
                       "full load (the light-load ramp shifts out lower: the helix adds the load torque to the "
                       "secondary clamp).</p>")
        rows = c.get("shift_out_vs_load") or []
        if rows:
            at_load = pred.get("shift_out_rpm_at_load") or [None] * len(rows)
            out.append(_table(["secondary load N·m", "engagement rpm", "shift-out rpm", "95 %", "sim truth rpm",
                               "tune predicts rpm"],
                              [[_f(r.get("torque_secondary_nm"), ".2f"), _f(r.get("engagement_rpm"), ".0f"),
                                _f(r.get("shift_out_rpm"), ".0f"), "± " + _f(r.get("shift_out_rpm_ci95"), ".0f"),
                                _f(r.get("shift_out_rpm_true"), ".0f"), _f(pl, ".0f")]
                               for r, pl in zip(rows, at_load)]))
            fl = c.get("shift_out_flatness") or {}
            out.append(f"<p>Shift-out flatness: {_f(fl.get('slope_rpm_per_nm'), '.1f')} ± "
                       f"{_f(fl.get('slope_ci95_rpm_per_nm'), '.1f')} rpm per N·m of load, spread "
                       f"{_f(fl.get('spread_rpm'), '.0f')} rpm over the loads (0 = perfectly flat).</p>")
        bs = c.get("back_shift") or {}
        if bs:
            out.append(f"<p>Back-shift under a load step: ratio {_f(bs.get('ratio_before'), '.3f')} → "
                       f"{_f(bs.get('ratio_after'), '.3f')}, 63 % after {_f(bs.get('t63_s'), '.1f')} s.</p>")
    if "loss_fit" in c:
        f = c["loss_fit"]
        co = f["coefficients"]
        out.append(_embed(loss_svg(c), "fig-loss", "loss torque vs secondary speed"))
        out.append(f"<p>Driven-side loss torque (secondary) from the coast-down, fitted over "
                   f"{_f(f['rpm_min'], '.0f')}–{_f(f['rpm_max'], '.0f')} rpm ({f['n_revolutions']} revolutions, "
                   f"inertia {f['inertia_kg_m2']:g} kg·m² ± {100 * f['inertia_rel_unc']:.0f} %): "
                   f"T = {co['a_nm']:.4f} + {co['b_nm_per_rad_s']:.3e}·ω + {co['c_nm_per_rad_s2']:.3e}·ω² N·m.</p>")
        true = c.get("loss_torque_true_nm") or [None] * len(f["rpm_grid"])
        rows = [[_f(r, ".0f"), _f(t, ".4f"), "± " + _f(s, ".4f"), "± " + _f(y, ".4f"), _f(tt, ".4f")]
                for r, t, s, y, tt in zip(f["rpm_grid"], f["torque_nm"], f["torque_ci95_nm"],
                                          f["torque_sys95_nm"], true)]
        out.append(_table(["secondary rpm", "loss N·m", "statistical 95 %", "inertia 95 %", "sim truth N·m"], rows))
        out.append(f"<p>Seen by the torque gauge (beyond it: pad drag): {_f(c.get('seen_nm'), '.3f')} ± "
                   f"{_f(c.get('seen_ci95_nm'), '.3f')} N·m; the rest is the loss to add back to efficiency "
                   "(<code>driven_loss.json</code>).</p>")
    return "".join(out)


def torque_zero(docs: list) -> str:
    if not docs:
        return ""
    z = docs[-1]
    b, a = z.get("before") or {}, z.get("after") or {}
    cls = "bad" if z.get("flagged") else "ok"
    verdict = escape(z.get("note") or "within the limit")
    return (f"<p>Zero at rest before GO {_f(b.get('torque_nm'), '.3f')} ± {_f(b.get('ci95_nm'), '.3f')} N·m, "
            f"after the last point {_f(a.get('torque_nm'), '.3f')} ± {_f(a.get('ci95_nm'), '.3f')} N·m: drift "
            f"{_f(z.get('drift_nm'), '+.3f')} ± {_f(z.get('drift_ci95_nm'), '.3f')} N·m (limit "
            f"{_f(z.get('drift_max_nm'), 'g')} N·m) — <span class=\"{cls}\">{verdict}</span>"
            f"{'; drift-corrected efficiencies are in the run JSON' if z.get('correct') else ''}.</p>")


def drive_grid(cells: list, points: list) -> str:
    """The drive grid as a table: a row per secondary-speed setpoint, a column per throttle; each cell its
    efficiency (%) ± the 95 % CI and the systematic 95 %, torque, output power and ratio, or why it has none."""
    from dyno.analysis.drive_grid import grid_table

    g = grid_table(cells, points)
    at = {(c["throttle_frac"], c["setpoint_rpm"]): c for c in g["cells"]}

    def cell(c) -> str:
        if c is None:
            return "—"
        if c["index"] is None:
            return f'<span class="warn">{escape(c["reason"] or "")}</span>'
        eff = (f"<b>{_f(c['efficiency'], '.1f', 100)} %</b> ± {_f(c['efficiency_ci95'], '.1f', 100)} pp "
               f"(sys ± {_f(c['efficiency_sys95'], '.1f', 100)} pp)" if c["efficiency"] is not None
               else f'<span class="warn">efficiency: {escape(c["reason"] or "undefined")}</span>')
        truth = f"; sim truth {_f(c['efficiency_true'], '.1f', 100)} %" if c.get("efficiency_true") is not None else ""
        return (f"{eff}{truth}<br>{_f(c['torque_secondary_nm'], '.2f')} N·m, {_f(c['power_out_w'], '.2f', 1e-3)} kW, "
                f"ratio {_f(c['ratio'], '.3f')}, engine {_f(c['rpm_primary'], '.0f')} rpm (point {c['index']})")

    head = ["secondary setpoint, rpm"] + [f"throttle {100 * u:.0f} %" for u in g["throttles"]]
    rows = [[_f(sp, ".0f")] + [cell(at.get((u, sp))) for u in g["throttles"]] for sp in g["setpoints_rpm"]]
    n = sum(c["index"] is not None for c in g["cells"])
    return (f"<p>{n} of {len(g['cells'])} cells measured; efficiency ± its 95 % CI and (sys) the systematic 95 % "
            "(torque calibration, engine map); each part-throttle efficiency uses the engine map's curve at that "
            "throttle.</p>" + _table(head, rows))
