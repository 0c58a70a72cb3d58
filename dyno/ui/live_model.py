"""What the live run screen shows, computed from the poller and controller (pure, no Textual).

The screen refreshes a few times a second and reads these; nothing here
blocks or does I/O, so a refresh costs well under a millisecond and never
delays the poller that shares the event loop.
"""

from __future__ import annotations

import math
from collections import deque

from dyno.analysis.live import LiveValues

TEST_STATES = ("warmup", "step", "settle", "measure")  # a test is under way (the ETA means something)


def measure_text(elapsed_s: float, plan) -> str:
    """MEASURE's clock: elapsed / cap in rig seconds, and what ends it sooner (``plan``: unscaled)."""
    if plan.target_efficiency_ci95 is not None:
        target = f"CI95 ±{plan.target_efficiency_ci95 * 100:.2g} pp"
    else:
        target = f"s.e. ≤ {plan.target_efficiency_sem * 100:.2g} pp"
    # short: with the point count and the ETA it stays on one line of 80 columns
    return (f"{min(elapsed_s, plan.max_measure_s):.0f} / {plan.max_measure_s:.0f} s "
            f"(≥ {plan.measure_s:.0f} s, until {target})")


def progress_text(state: str, n_points: int, total: int | None, eta_s: float | None) -> str:
    """``point n/~N  ETA m:ss`` of a running test (the headless progress line's words), else ''."""
    from dyno.control.progress import eta_text, points_text

    if state not in TEST_STATES:
        return ""
    return f"{points_text(n_points, total)}  {eta_text(eta_s)}"


def discard_text(discards: list) -> str:
    """The last discarded measurement window and why (the controller measures it again), or ''."""
    if not discards:
        return ""
    d = discards[-1]
    many = f"{len(discards)} windows discarded" if len(discards) > 1 else "window discarded"
    return f"{many}; last: point {d.get('index', 0) + 1}, try {d.get('attempt', 1)}: {d.get('reason', '?')}"


def temp_colour(temp_c: float, limit_c: float, ambient_c: float = 25.0) -> tuple[str, str]:
    """(colour, marker) for the rotor temperature: green at ambient -> yellow -> red at the limit.

    The marker ('', ' warm', ' HOT', ' OVER LIMIT') carries the same meaning on
    a terminal without colour.
    """
    if math.isnan(temp_c):
        return "#888888", " (no reading)"
    f = (temp_c - ambient_c) / max(1e-9, limit_c - ambient_c)
    f = min(1.0, max(0.0, f))
    if f < 0.5:  # green -> yellow
        r, g = int(510 * f), 200
    else:  # yellow -> red
        r, g = 255, int(200 * (1.0 - f) * 2)
    marker = " OVER LIMIT" if temp_c >= limit_c else (" HOT" if f >= 0.8 else (" warm" if f >= 0.5 else ""))
    return f"#{min(r, 255):02x}{g:02x}00", marker


def last_point_text(points: list) -> tuple[str, str]:
    """The last point's total 95 % half-width and its interval, for the points row and the row under it:
    ``("U95 ±x pp", "a…b %")`` (``efficiency_interval95``: where the truth lies at 95 % with the window's scatter,
    the calibration, the engine map, the air and the driveline, asymmetric where a term is, dyno.analysis.systematic;
    ``efficiency_u95``: half its width, the same statement; the CI alone is on the measuring line); ``("", "")``
    before a point."""
    p = next((q for q in reversed(points) if isinstance(q.get("efficiency"), float)
              and math.isfinite(q["efficiency"])), None)
    if p is None:
        return "", ""
    iv = p.get("efficiency_interval95")
    interval = f"{iv[0] * 100:.1f}…{iv[1] * 100:.1f} %" if iv and None not in iv else ""
    return f"U95 ±{fmt(p.get('efficiency_u95', math.nan) * 100, '.1f')} pp", interval


def efficiency_text(v: LiveValues, loaded: bool) -> str:
    """The efficiency readout: ``—`` unless the test holds a steady load (``loaded``), ``n/a: why`` when the
    engine map gives no denominator (no curve at the commanded throttle, speed off the map)."""
    if not loaded:
        return "—"
    if math.isnan(v.efficiency):
        if v.efficiency_reason is None or not math.isnan(v.power_engine_w):
            return "—"  # no speed or no torque yet: nothing to explain
        return f"n/a: {v.efficiency_reason}"
    return fmt(v.efficiency * 100, ".1f", " %")


def go_text(plan) -> tuple[str, str]:
    """What GO will move under ``plan``, in the operator's words: (the dialog's sentence, the message after)."""
    mode = plan.mode
    if mode == "engagement":
        return ("From idle the THROTTLE RAMPS up to 90 % through the shift; the brake then steps the load.",
                "GO: throttle ramp from idle")
    if mode == "coast-down":
        return ("Throttle goes to FULL with the brake released, then the ENGINE IS CUT and the rig coasts to rest.",
                "GO: full throttle, then engine cut and coast-down")
    if mode == "speed-hold":
        n = getattr(plan.params, "points", None)
        many = f"{n} " if isinstance(n, int) else ""
        return (f"Throttle goes to FULL; the brake finds its contact point, then HOLDS the secondary at {many}speed "
                "setpoints down the range (closed loop).", "GO: full throttle, brake holding speed setpoints")
    if mode == "drive-grid":
        return ("For each throttle of the grid the brake is released, the THROTTLE SET, then the brake HOLDS the "
                "secondary at each reachable speed (closed loop).", "GO: throttle x speed grid, brake holding")
    if mode == "steps":
        def variables(kind: str) -> list[str]:
            return sorted({str(st.get("variable")) for st in getattr(plan.params, "steps", None) or ()
                           if isinstance(st, dict) and st.get("kind") == kind and st.get("variable")})

        holds, ramps = variables("hold"), variables("ramp")
        moves = ([f"HOLDS {' and '.join(holds)} setpoints in turn"] if holds else []) + \
                ([f"RAMPS the {' and '.join(ramps)} speed down its range"] if ramps else [])
        what = "; then ".join(moves) or "HOLDS the plan's setpoints in turn"
        return (f"Throttle goes to FULL; the brake {what} (closed loop).", f"GO: full throttle, brake {what.lower()}")
    return ("Throttle goes to FULL and the brake starts stepping (open-loop steps).", "GO: full throttle, brake stepping")


def fmt(x: float, spec: str = ".0f", unit: str = "") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    text = f"{x:{spec}}"
    if text.startswith("-") and float(text) == 0.0:
        text = text[1:]  # "-0" is noise around zero, not a direction
    return f"{text}{unit}"


class History:
    """Ring buffers of the last ``span_s`` of live values, for the time plot and the shift-curve trail."""

    def __init__(self, span_s: float = 30.0) -> None:
        self.span_s = span_s
        self.t: deque = deque()
        self.rpm_primary: deque = deque()
        self.rpm_secondary: deque = deque()
        self.torque_nm: deque = deque()

    def add(self, t_s: float, v: LiveValues) -> None:
        self.t.append(t_s)
        self.rpm_primary.append(v.rpm_primary)
        self.rpm_secondary.append(v.rpm_secondary)
        self.torque_nm.append(v.torque_secondary_nm)
        while self.t and t_s - self.t[0] > self.span_s:
            for d in (self.t, self.rpm_primary, self.rpm_secondary, self.torque_nm):
                d.popleft()
