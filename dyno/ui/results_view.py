"""The live screen's results panel: a characterisation plan's figures as text (pure, no Textual).

The figures are the controller's ``results`` -- the dict the plan's runner computed
(:mod:`dyno.control.plans.characterise`, :mod:`dyno.control.plans.coastdown`) and stored with the run as its
``characterisation`` document; ``dyno run --json`` prints the same dict and report.html renders it
(:func:`dyno.report.sections.characterisation`).  This module only lays it out in ~50 columns.
"""

from __future__ import annotations

import math

WIDTH = 49  # the plot's column of an 80-column screen (80 - the values' 30 - margins)


def _ok(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _f(v, spec: str) -> str:
    return format(v, spec) if _ok(v) else "—"


def has_results(results: dict | None) -> bool:
    """True when ``results`` holds a characterisation this panel knows how to show."""
    return bool(results) and ("engagement_rpm" in results or "loss_fit" in results)


def results_lines(results: dict) -> list[str]:
    """The panel's lines (each at most :data:`WIDTH` characters) for an engagement or coast-down result."""
    if not has_results(results):
        return ["no characterisation results"]
    out = engagement_lines(results) if "engagement_rpm" in results else []
    if "loss_fit" in results:
        out += coast_down_lines(results)
    if _ok(results.get("test_time_s")):
        out.append(f"test {results['test_time_s']:.0f} s of rig time; all in report.html")
    return [line[:WIDTH] for line in out]


# (key, label, format of the value and of its 95 % half-width)
ENGAGEMENT_ROWS = (("engagement_rpm", "engagement rpm", ".0f"), ("lockup_rpm", "lock-up rpm", ".0f"),
                   ("shift_out_rpm", "shift-out rpm", ".0f"), ("full_shift_ratio", "full-shift ratio", ".4f"),
                   ("low_ratio", "low-gear ratio", ".4f"))


def engagement_lines(r: dict) -> list[str]:
    truth = any(f"{k}_true" in r for k, _, _ in ENGAGEMENT_ROWS)
    out = ["ENGAGEMENT / SHIFT-OUT (engine rpm, ± 95 %)",
           f"{'':17}{'measured':>8} {'± 95 %':<9}" + (f"{'sim truth':>10}" if truth else "")]
    for key, label, spec in ENGAGEMENT_ROWS:
        if key not in r:
            continue
        line = f"{label:<17}{_f(r.get(key), spec):>8} ± {_f(r.get(f'{key}_ci95'), spec):<7}"
        if truth:
            line += f"{_f(r.get(f'{key}_true'), spec):>10}"
        out.append(line)
    out.append("ratio = engine rpm / secondary rpm")
    pred = r.get("predicted") or {}
    if _ok(pred.get("engagement_rpm")) or _ok(pred.get("shift_out_rpm")):
        out.append(f"tune predicts {_f(pred.get('engagement_rpm'), '.0f')} engagement, "
                   f"{_f(pred.get('shift_out_rpm'), '.0f')} shift-out")
    elif pred.get("error"):
        out.append(f"tune prediction failed: {pred['error']}")
    rows = r.get("shift_out_vs_load") or []
    if rows:
        out.append("shift-out vs secondary load:")
        for row in rows:
            out.append(f"  {_f(row.get('torque_secondary_nm'), '5.2f')} N·m: {_f(row.get('shift_out_rpm'), '.0f')}"
                       f" ± {_f(row.get('shift_out_rpm_ci95'), '.0f')} rpm"
                       + (f"  (truth {_f(row.get('shift_out_rpm_true'), '.0f')})" if "shift_out_rpm_true" in row
                          else ""))
        fl = r.get("shift_out_flatness") or {}
        if fl:
            out.append(f"  slope {_f(fl.get('slope_rpm_per_nm'), '.0f')} ± {_f(fl.get('slope_ci95_rpm_per_nm'), '.0f')}"
                       f" rpm per N·m (0 = flat)")
    bs = r.get("back_shift") or {}
    if bs:
        out.append(f"back-shift: ratio {_f(bs.get('ratio_before'), '.3f')} → {_f(bs.get('ratio_after'), '.3f')}, "
                   f"63 % in {_f(bs.get('t63_s'), '.1f')} s")
    return out


def coast_down_lines(r: dict) -> list[str]:
    f = r["loss_fit"]
    co = f.get("coefficients") or {}
    out = ["COAST-DOWN: driven-side loss at the secondary",
           "T = a + b·ω + c·ω² (ω in rad/s)",  # (two lines: the pane beside the 32-column fields is 46 wide)
           f"  over {_f(f.get('rpm_min'), '.0f')}–{_f(f.get('rpm_max'), '.0f')} rpm",
           f"  a = {_f(co.get('a_nm'), '.4f')} N·m",
           f"  b = {_f(co.get('b_nm_per_rad_s'), '.3e')} N·m per rad/s",
           f"  c = {_f(co.get('c_nm_per_rad_s2'), '.3e')} N·m per (rad/s)²"]
    grid, torque = f.get("rpm_grid") or [], f.get("torque_nm") or []
    stat, sys_ = f.get("torque_ci95_nm") or [], f.get("torque_sys95_nm") or []
    true = r.get("loss_torque_true_nm") or []
    if grid and len(torque) == len(grid):
        out.append(f"{'secondary rpm':>13} {'loss N·m':>9} {'± 95 %':>7}" + (f" {'sim truth':>10}" if true else ""))
        n = len(grid)
        for i in sorted({0, n // 2, n - 1}):
            half = math.hypot(stat[i], sys_[i]) if i < len(stat) and i < len(sys_) else math.nan
            out.append(f"{_f(grid[i], '.0f'):>13} {_f(torque[i], '.4f'):>9} {_f(half, '.4f'):>7}"
                       + (f" {_f(true[i], '.4f'):>10}" if i < len(true) else ""))
    if _ok(r.get("loss_torque_max_rel_error")):
        out.append(f"max error against the sim's truth {100 * r['loss_torque_max_rel_error']:.2f} %")
    if _ok(r.get("seen_nm")):
        out.append(f"seen by the torque gauge {_f(r.get('seen_nm'), '.3f')} ± {_f(r.get('seen_ci95_nm'), '.3f')} N·m")
    if _ok(f.get("inertia_kg_m2")):
        out.append(f"inertia {f['inertia_kg_m2']:g} kg·m² ± {100 * f.get('inertia_rel_unc', 0.0):.0f} %, "
                   f"{f.get('n_revolutions', '?')} revolutions")
    out.append("saved: driven_loss.json (for --driven-loss)")
    return out
