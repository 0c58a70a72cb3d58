"""The report's figures as SVG text: matplotlib in memory (no display, no pyplot state, no files).

Every plotted artist carries an SVG id (``gid``) naming its series, so a reader (or a test) can find the
points of, say, ``eff-points`` in the figure; the numbers plotted are the ones in the report's JSON block.
Units as a person reads them: rpm, N·m, kW, efficiency in %.
"""

from __future__ import annotations

import io
import math

#: deterministic SVG ids and text kept as text (smaller, searchable)
_RC = {"svg.fonttype": "none", "svg.hashsalt": "dyno-report", "font.size": 9, "axes.grid": True,
       "grid.alpha": 0.3}


def new_figure(width_in: float = 7.0, height_in: float = 4.2, ncols: int = 1):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=100, layout="constrained")
    axes = [fig.add_subplot(1, ncols, k + 1) for k in range(ncols)]
    return fig, axes


def svg_text(fig) -> str:
    buf = io.StringIO()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    return buf.getvalue()


def _pct(values) -> list[float]:
    return [100.0 * v for v in values]


def _plain(values) -> list[float]:
    return [math.nan if v is None else float(v) for v in values]


def legend_or_note(ax) -> None:
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)
    else:  # say so, rather than leave an empty frame to be puzzled over
        ax.text(0.5, 0.5, "no points to plot", transform=ax.transAxes, ha="center", va="center", color="0.4")


def render_styled(draw) -> str:
    import matplotlib

    with matplotlib.rc_context(_RC):
        return draw()


def efficiency_svg(series: dict) -> str:
    """Efficiency (%) vs secondary rpm: valid points ± 1 standard error, excluded points, model, sim truth."""
    def draw() -> str:
        fig, (ax,) = new_figure()
        v = series["points"]
        if v["rpm_secondary"]:
            bars = ax.errorbar(v["rpm_secondary"], _pct(v["efficiency"]), yerr=_pct(v["efficiency_sem"]),
                               fmt="o", ms=4, capsize=3, color="C0", label="measured (± 1 standard error)")
            bars[0].set_gid("eff-points")
        x = series.get("excluded") or {}
        if x.get("rpm_secondary"):
            ax.plot(x["rpm_secondary"], _pct(_plain(x["efficiency"])), "x", color="0.55",
                    label="invalid / discarded", gid="eff-excluded")
        m = series.get("model")
        if m and m["rpm_secondary"]:  # the full model: a prediction with losses
            ax.plot(m["rpm_secondary"], _pct(m["efficiency"]), "-", color="C3", lw=1.2,
                    label="belt model (full, thesis BVP)", gid="eff-model")
        b = (m or {}).get("bound")
        if b and b["rpm_secondary"]:  # never drawn as if it were the prediction: dashed, named a bound
            ax.plot(b["rpm_secondary"], _pct(b["efficiency"]), "--", color="0.5", lw=1.0,
                    label="closed form: creep loss only (upper bound)", gid="eff-model-bound")
        t = series.get("truth")
        if t and t["rpm_secondary"]:
            ax.plot(t["rpm_secondary"], _pct(t["efficiency"]), ".", color="C2", ms=3,
                    label="simulated truth", gid="eff-truth")
        ax.set(xlabel="secondary speed, rpm", ylabel="efficiency, %", title="CVT efficiency")
        legend_or_note(ax)
        return svg_text(fig)

    return render_styled(draw)


def shift_svg(series: dict) -> str:
    """Shift curve: ratio (engine rpm / secondary rpm) vs engine rpm, measured and predicted from the tune."""
    def draw() -> str:
        fig, (ax,) = new_figure()
        v = series["points"]
        if v["rpm_primary"]:
            ax.plot(v["rpm_primary"], v["ratio"], "o", ms=4, color="C0", label="measured", gid="shift-points")
        p = series.get("predicted")
        if p and p["engine_rpm"]:
            ax.plot(p["engine_rpm"], p["ratio"], "-", color="C1", lw=1.2, label="predicted from the tune",
                    gid="shift-predicted")
        ax.set(xlabel="engine speed, rpm", ylabel="ratio (engine / secondary speed)", title="shift curve")
        legend_or_note(ax)
        return svg_text(fig)

    return render_styled(draw)


def torque_power_svg(series: dict) -> str:
    """Secondary torque (N·m) and output / input power (kW) vs secondary rpm."""
    def draw() -> str:
        fig, (ax_t, ax_p) = new_figure(9.0, 3.8, ncols=2)
        v = series["points"]
        if v["rpm_secondary"]:
            ax_t.plot(v["rpm_secondary"], v["torque_secondary_nm"], "o", ms=4, color="C0",
                      label="secondary torque", gid="torque-points")
            ax_p.plot(v["rpm_secondary"], [w / 1000.0 for w in v["power_out_w"]], "o", ms=4, color="C0",
                      label="output (secondary)", gid="power-out-points")
            ax_p.plot(v["rpm_secondary"], [w / 1000.0 for w in _plain(v["power_in_w"])], "s", ms=3.5,
                      color="C1", label="input (engine map)", gid="power-in-points")
        ax_t.set(xlabel="secondary speed, rpm", ylabel="torque, N·m", title="secondary torque")
        ax_p.set(xlabel="secondary speed, rpm", ylabel="power, kW", title="power")
        legend_or_note(ax_p)
        return svg_text(fig)

    return render_styled(draw)


def engine_map_svg(engine_map: dict) -> str:
    """The engine map the efficiencies were computed with: torque (N·m) and power (kW) vs engine rpm."""
    def draw() -> str:
        fig, (ax,) = new_figure(7.0, 3.6)
        ax.plot(engine_map["rpm"], engine_map["torque_nm"], "-", color="C0", label="torque", gid="map-torque")
        ax.set(xlabel="engine speed, rpm", ylabel="torque, N·m", title="engine map")
        ax2 = ax.twinx()
        ax2.grid(False)
        ax2.plot(engine_map["rpm"], [w / 1000.0 for w in engine_map["power_w"]], "--", color="C1",
                 label="power", gid="map-power")
        ax2.set_ylabel("power, kW")
        lines = ax.get_lines() + ax2.get_lines()
        ax.legend(lines, [ln.get_label() for ln in lines], fontsize=7, loc="lower center")
        return svg_text(fig)

    return render_styled(draw)
