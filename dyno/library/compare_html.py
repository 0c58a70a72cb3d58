"""The comparison as one self-contained HTML file (matplotlib figures inlined as SVG)."""

from __future__ import annotations

import html
import io

from dyno.library.compare import QUANTITIES

SCALE = {"efficiency": (100.0, "%"), "torque_secondary_nm": (1.0, "N·m"), "power_out_w": (1.0, "W"),
         "rpm_primary": (1.0, "rpm")}


def _svg(fig) -> str:
    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    text = buf.getvalue()
    return text[text.index("<svg"):]  # drop the XML prolog: the figure sits inside the HTML


def figures(result: dict) -> list[tuple[str, str]]:
    """(title, inline SVG) per figure: overlaid curves with ±1 s.e. bars, then the differences with 95 % bands."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    grid = np.array(result["grid_rpm_secondary"], dtype=float)
    out = []
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    for ax, q in zip(axes.flat, QUANTITIES):
        k, unit = SCALE[q]
        for c in result["curves"]:
            pts = c["points"][q]
            x = np.array(pts["rpm_secondary"], dtype=float)
            y = np.array(pts["value"], dtype=float) * k
            e = np.array(pts["sem"], dtype=float) * k
            line = ax.errorbar(x, y, yerr=e, fmt="o", ms=3, capsize=2, label=c["name"])
            ax.plot(grid, np.array(c[q]["value"], dtype=float) * k, "-", lw=1, color=line[0].get_color())
        ax.set_xlabel("secondary speed (rpm)")
        ax.set_ylabel(f"{QUANTITIES[q][3]} ({unit})")
        ax.grid(alpha=0.3)
    axes.flat[0].legend(fontsize=8)
    fig.suptitle("points ±1 standard error; lines: linear interpolation on the common grid")
    out.append(("Curves", _svg(fig)))
    plt.close(fig)
    for d in result["differences"]:
        fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
        for ax, q in zip(axes.flat, QUANTITIES):
            k, unit = SCALE[q]
            qd = d["quantities"][q]
            diff = np.array(qd["difference"], dtype=float) * k
            sem = np.array(qd["sem"], dtype=float) * k
            sig = np.array([bool(s) for s in qd["significant"]])
            if qd.get("difference_u95"):  # the stated U95: everything that does not cancel between the runs
                u = np.array(qd["difference_u95"], dtype=float) * k
                ax.fill_between(grid, -u, u, color="0.93", label="±U95 (all terms not cancelled)")
            ax.fill_between(grid, -1.96 * sem, 1.96 * sem, color="0.85", label="±1.96 s.e. (95 %)")
            ax.axhline(0.0, color="0.5", lw=0.8)
            ax.plot(grid, diff, "-", color="C0", lw=1)
            ax.plot(grid[sig], diff[sig], "o", color="C3", ms=5, label="significant")
            ax.plot(grid[~sig], diff[~sig], "o", color="C0", mfc="none", ms=5, label="not significant")
            if "truth_difference" in qd:
                ax.plot(grid, np.array(qd["truth_difference"], dtype=float) * k, "--", color="C2", lw=1,
                        label="simulation truth")
            ax.set_xlabel("secondary speed (rpm)")
            ax.set_ylabel(f"Δ {QUANTITIES[q][3]} ({unit})")
            ax.grid(alpha=0.3)
        axes.flat[0].legend(fontsize=7)
        fig.suptitle(f"{d['name']} − {d['reference']}")
        out.append((f"Difference: {d['name']} − {d['reference']}", _svg(fig)))
        plt.close(fig)
    return out


def _cell(v) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.6g}"
    return html.escape(str(v))


def render(result: dict) -> str:
    e = html.escape
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'><title>dyno compare</title><style>",
             "body{font-family:sans-serif;margin:1.5em;max-width:1200px}table{border-collapse:collapse;margin:.5em 0}",
             "td,th{border:1px solid #bbb;padding:2px 6px;font-size:13px;text-align:right}th{background:#eee}",
             ".sig{color:#b00;font-weight:bold}.l{text-align:left}</style></head><body>",
             "<h1>Run comparison</h1><table><tr><th class=l>run</th><th class=l>path</th><th>state</th><th>points</th></tr>"]
    for r in result["runs"]:
        parts.append(f"<tr><td class=l>{e(r['name'])}</td><td class=l>{e(str(r['path']))}</td>"
                     f"<td>{_cell(r['state'])}</td><td>{_cell(r['n_points'])}</td></tr>")
    parts.append(f"</table><p>{e(result['atmosphere'])}.</p>")
    parts.append(f"<p>Common grid: {len(result['grid_rpm_secondary'])} secondary speeds every "
                 f"{result['step_rpm']:g} rpm inside the range all runs cover. A difference is "
                 "<span class=sig>significant</span> when |Δ| &gt; 1.96 s.e. (95 %); the s.e. combines the points' "
                 "standard errors and the linear interpolation's curvature error.</p>")
    for d in result["differences"]:
        parts.append(f"<h2>{e(d['name'])} against {e(d['reference'])}</h2><h3>Tune diff</h3>")
        if d["tune_diff"]:
            parts.append("<table><tr><th class=l>parameter</th><th>from</th><th>to</th></tr>")
            parts += [f"<tr><td class=l>{e(t['key'])}</td><td>{_cell(t['from'])}</td><td>{_cell(t['to'])}</td></tr>"
                      for t in d["tune_diff"]]
            parts.append("</table>")
        else:
            parts.append("<p>same tune</p>")
        if d["setup_diff"]:
            parts.append("<h3>Other differences in the setup</h3><table><tr><th class=l>field</th><th>from</th>"
                         "<th>to</th></tr>")
            parts += [f"<tr><td class=l>{e(t['key'])}</td><td>{_cell(t['from'])}</td><td>{_cell(t['to'])}</td></tr>"
                      for t in d["setup_diff"]]
            parts.append("</table>")
        if d.get("terms"):
            parts.append("<h3>What cancels in the efficiency difference</h3><table><tr><th class=l>term</th>"
                         "<th class=l>status</th><th>largest U95 (points)</th><th class=l>why</th></tr>")
            for k, t in d["terms"].items():
                top = "—" if t["max_u95"] is None else f"{100 * t['max_u95']:.2f}"
                parts.append(f"<tr><td class=l>{e(k)}</td><td class=l>{e(t['status'])}</td><td>{top}</td>"
                             f"<td class=l>{e(t['reason'])}</td></tr>")
            parts.append("</table>")
        parts.append("<h3>Point-wise differences</h3><table><tr><th>rpm_s</th>")
        parts += [f"<th>Δ {e(QUANTITIES[q][3])} ({SCALE[q][1]})</th>" for q in QUANTITIES]
        parts.append("</tr>")
        for i, g in enumerate(result["grid_rpm_secondary"]):
            row = [f"<td>{g:.0f}</td>"]
            for q in QUANTITIES:
                qd = d["quantities"][q]
                k = SCALE[q][0]
                v, s = qd["difference"][i], qd["sem"][i]
                if v is None or s is None:
                    row.append("<td>—</td>")
                    continue
                cls = " class=sig" if qd["significant"][i] else ""
                row.append(f"<td{cls}>{v * k:+.3g} ± {s * k:.2g}{' *' if qd['significant'][i] else ''}</td>")
            parts.append("<tr>" + "".join(row) + "</tr>")
        parts.append("</table><p>* significant at 95 %</p>")
    for title, svg in figures(result):
        parts.append(f"<h2>{e(title)}</h2>{svg}")
    parts.append("</body></html>\n")
    return "".join(parts)
