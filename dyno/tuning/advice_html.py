"""The advice as one self-contained HTML page: the ranked tunes, their predicted figures with u,
and their predicted shift curves at the calibrated part values beside the targets (inline SVG)."""

from __future__ import annotations

import html
import io
import math


def _svg(fig) -> str:
    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    text = buf.getvalue()
    return text[text.index("<svg"):]


def curves_figure(curves: list[tuple[str, object]], targets: dict) -> str:
    """Engine rpm vs secondary rpm of each tune's predicted curve, the targets as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5.5))
    for name, curve in curves:
        if curve is None or not curve.points:
            continue
        a = curve.arrays()
        ax.plot(a["secondary_rpm"], a["engine_rpm"], "-", lw=1.5, label=name)
    styles = {"engagement_rpm": ":", "shift_out_rpm": "--", "full_load_rpm": "-."}
    for k, v in targets.items():
        ax.axhline(v, color="k", ls=styles.get(k, ":"), lw=0.8)
        ax.annotate(f"target {k.removesuffix('_rpm')} {v:.0f}", (0, v), xytext=(4, 3), textcoords="offset points",
                    fontsize=8)
    ax.set_xlabel("secondary rpm")
    ax.set_ylabel("engine rpm")
    ax.set_title("predicted shift curves (full throttle, calibrated part values)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    out = _svg(fig)
    plt.close(fig)
    return out


def render(advice: dict, curves_svg: str | None) -> str:
    e = html.escape
    rows = []
    for i, t in enumerate(advice["tunes"], 1):
        ch = "<br>".join(f"{e(c['kind'])}: {e(c['label'])} <small>({e(c['part'])}; {e(c['source'])})</small>"
                         for c in t["changes"]) or "no change"
        pr = "<br>".join(f"{e(f)} {v['rpm']:.0f} ± {v['u95_rpm']:.0f} rpm" for f, v in t["predicted"].items()
                         if math.isfinite(v["rpm"]))
        p2 = t.get("p_within_two_trips", t["p_within_tolerance"])
        rows.append(f"<tr><td>{i}</td><td>{ch}</td><td>{pr}</td><td>{t['p_within_tolerance']:.2f}</td>"
                    f"<td>{p2:.2f}</td><td><code>{e(t['tune_file'])}</code></td></tr>")
    cur = advice["current"]["predicted"]
    cur_txt = ", ".join(f"{e(f)} {v['rpm']:.0f} ± {v['u95_rpm']:.0f}" for f, v in cur.items())
    cal_rows = "".join(
        f"<tr><td>{e(p['part'])}</td><td>{e(p['field'])}</td><td>{100 * p['deviation_rel']:+.1f} %</td>"
        f"<td>{100 * p['u_rel']:.1f} % (prior {100 * p['prior_sd_rel']:.1f} %)</td></tr>"
        for p in advice["calibration"]["parameters"])
    targets = ", ".join(f"{e(k)} {v:.0f} rpm" for k, v in advice["targets"].items())
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>dyno tune advice</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:1em auto}}td,th{{border-bottom:1px solid #ccc;
padding:3px 8px;vertical-align:top}}table{{border-collapse:collapse}}</style></head><body>
<h1>Tune advice</h1>
<p>Targets: {targets} (within ±{advice['tolerance_rpm']:.0f} rpm); at most {advice['max_changes']} parts changed;
{advice['searched']} tunes searched. Runs: {e(', '.join(advice['runs']))}.</p>
<p>The current tune ({e(advice['base_tune'])}), calibrated: {cur_txt} rpm (± U95).</p>
<p><strong>{e(advice.get('verdict', ''))}</strong></p>
<h2>Ranked tunes</h2>
<table><tr><th>#</th><th>parts changed</th><th>predicted (± U95)</th><th>P(all targets met)</th><th>P(met, or after one adjustment of the same parts)</th><th>tune file</th></tr>
{''.join(rows)}</table>
<h2>Predicted shift curves</h2>
{curves_svg or '<p>(no engine map with the run: no curves)</p>'}
<h2>Calibration: the parts' effective values</h2>
<p>Relative deviation of each part from its label, from the runs (MAP with the part's stated tolerance as
prior); u is the posterior standard uncertainty. chi²/figure {advice['calibration']['chi2_per_figure']:.2f}.</p>
<table><tr><th>part</th><th>field</th><th>deviation</th><th>u</th></tr>{cal_rows}</table>
</body></html>
"""
