"""One frame of the live page: the values the terminal UI shows, as plain JSON-ready data (pure, no I/O).

Built on the rig's loop by :class:`dyno.web.feed.LiveFeed` (copies of numbers and short strings, a few
hundred microseconds), encoded to JSON in the server's thread.
"""

from __future__ import annotations

import math
import time

from dyno.analysis.live import RateMeter, live_values

#: the points table's columns (a subset of dyno.summary.POINT_KEYS)
POINT_COLUMNS = ("index", "rpm_primary", "rpm_secondary", "ratio", "torque_secondary_nm", "power_out_w",
                 "power_in_w", "efficiency", "efficiency_ci95", "efficiency_u95", "efficiency_interval95", "valid")


def _num(x):
    """A finite float, else None (JSON has no NaN)."""
    if x is None or isinstance(x, bool):
        return x
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def point_row(p: dict) -> dict:
    return {k: (p.get(k) if k == "valid" else _interval(p.get(k)) if k.endswith("_interval95") else _num(p.get(k)))
            for k in POINT_COLUMNS}


def _interval(iv):
    """``[low, high]`` with finite ends, else None."""
    if not isinstance(iv, (list, tuple)) or len(iv) != 2:
        return None
    lo, hi = _num(iv[0]), _num(iv[1])
    return None if lo is None or hi is None else [lo, hi]


class SnapshotBuilder:
    """Keeps what a frame needs between frames (the frame-rate meter, the converted points)."""

    def __init__(self) -> None:
        self.rate = RateMeter()
        self._rows: list = []
        self._rows_of = None  # the controller the rows came from (a re-armed session starts a new list)

    def rows(self, controller) -> list:
        pts = controller.points
        if self._rows_of is not controller or len(self._rows) > len(pts):
            self._rows, self._rows_of = [], controller
        while len(self._rows) < len(pts):  # points are final once appended: convert each once
            self._rows.append(point_row(pts[len(self._rows)]))
        return list(self._rows)

    def build(self, poller, controller, now_s: float, *, progress=(None, None, None), rig_safe=None,
              run_dir=None, t_sim_s=None) -> dict:
        """``progress``: (points so far, estimated total, wall seconds left); ``rig_safe``: True/False from
        the rig's outputs when they can tell (the simulated physics), None when only commanded."""
        v = live_values(poller, controller, now_s, self.rate)
        rows = self.rows(controller)
        last = next((r for r in reversed(rows) if r.get("efficiency") is not None), None)
        n, total, eta_s = progress
        aborts = controller.aborts
        return {
            "wall_unix_s": time.time(), "t_sim_s": _num(t_sim_s if t_sim_s is not None else now_s),
            "state": v.state, "reason": v.reason, "paused": bool(v.paused), "run_dir": run_dir,
            "rpm_primary": _num(v.rpm_primary), "rpm_secondary": _num(v.rpm_secondary),
            "ratio": _num(v.ratio), "torque_secondary_nm": _num(v.torque_secondary_nm),
            "power_out_w": _num(v.power_out_w), "power_engine_w": _num(v.power_engine_w),
            "efficiency_live": _num(v.efficiency), "efficiency_reason": v.efficiency_reason,
            # the last point's efficiency and its 95 % half-widths (statistical; total with the systematic terms)
            "efficiency": last["efficiency"] if last else None,
            "efficiency_ci95": last["efficiency_ci95"] if last else None,
            "efficiency_u95": last["efficiency_u95"] if last else None,
            "efficiency_interval95": last["efficiency_interval95"] if last else None,  # [low, high]
            "rotor_temp_c": _num(v.rotor_temp_c), "rotor_temp_limit_c": _num(v.rotor_temp_limit_c),
            "throttle_frac": _num(v.throttle_frac), "frames_per_s": _num(v.frames_per_s),
            "crc_errors": v.crc_errors, "events_lost": v.events_lost, "run_enable": v.run_enable,
            "points_done": len(rows) if n is None else n, "points_total_est": total, "eta_s": _num(eta_s),
            "abort_cause": v.abort_cause, "abort_detail": v.abort_detail,
            "aborts": [{"cause": a.get("cause"), "detail": a.get("detail")} for a in aborts],
            "rig_safe": rig_safe, "points": rows,
        }
