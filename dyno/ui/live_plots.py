"""The live screen's three plots, drawn on a plotext figure (``textual_plotext``'s ``plt``).

Split from :mod:`dyno.ui.live_app` along the drawing seam: each function only reads what it is given
(points, the value history, the overlay's curves) and draws; when to redraw is the screen's business.
"""

from __future__ import annotations

import math

PLOTS = {"1": "efficiency", "2": "shift curve", "3": "torque/rpm vs time"}


def draw_efficiency(plt, points, overlay_full=None, overlay_rough=None) -> None:
    """Measured efficiency vs secondary rpm (error bars: the s.e.), invalid points marked; with the
    belt-model overlay: the full model's curve and, for the points it has not solved yet, the closed form."""
    shown = [p for p in points if p.get("efficiency") is not None and math.isfinite(p["efficiency"])]
    good = [p for p in shown if p.get("valid", True)]
    bad = [p for p in shown if not p.get("valid", True)]  # windows disturbed every time, or outside 0..1
    plt.title("efficiency vs secondary rpm")
    plt.xlabel("secondary rpm")
    plt.ylabel("%")
    if good:
        xs = [p["rpm_secondary"] for p in good]
        ys = [p["efficiency"] * 100 for p in good]
        es = [(p.get("efficiency_sem") or 0.0) * 100 for p in good]
        plt.error(xs, ys, yerr=es, color="cyan", label="measured")
    if bad:
        plt.scatter([p["rpm_secondary"] for p in bad], [p["efficiency"] * 100 for p in bad], marker="x",
                    color="red", label="invalid (see status)")
    if overlay_full:
        pred = sorted(overlay_full)
        plt.plot([a for a, _ in pred], [b * 100 for _, b in pred], color="green", marker="dot",
                 label="model (full)")
    if overlay_rough:
        rough = sorted(overlay_rough)  # not solved yet: the closed form (creep only, an upper bound)
        plt.scatter([a for a, _ in rough], [b * 100 for _, b in rough], color="gray", marker="x",
                    label="model (closed form, solving)")


def draw_shift_curve(plt, history, points, ideal_rpm: float) -> None:
    """Engine rpm vs secondary rpm: the live trail, the points, and the ideal (peak-power) engine speed."""
    plt.title(f"shift curve; ideal {ideal_rpm:.0f} rpm (peak power)")
    plt.xlabel("secondary rpm")
    plt.ylabel("engine rpm")
    h = history
    trail = [(b, a) for a, b in zip(h.rpm_primary, h.rpm_secondary) if b > 0 and a > 0]
    if trail:
        plt.scatter([x for x, _ in trail], [y for _, y in trail], marker="dot", color="gray", label="live")
    if points:
        plt.scatter([p["rpm_secondary"] for p in points], [p["rpm_primary"] for p in points], color="cyan",
                    label="points")
    if math.isfinite(ideal_rpm):
        plt.hline(ideal_rpm, color="green")  # the flat engine speed a perfect CVT would hold


def draw_time(plt, history) -> None:
    """The last ``history.span_s``: engine and secondary rpm (left axis), torque (right)."""
    h = history
    plt.title("last 30 s: rpm (left), torque N·m (right)")
    t = list(h.t)
    if t:
        plt.plot(t, [x if math.isfinite(x) else 0 for x in h.rpm_primary], color="yellow", label="engine")
        plt.plot(t, [x if math.isfinite(x) else 0 for x in h.rpm_secondary], color="cyan",
                 label="secondary")
        plt.plot(t, [x if math.isfinite(x) else 0 for x in h.torque_nm], color="magenta", yside="right",
                 label="torque")
    plt.xlabel("s")
