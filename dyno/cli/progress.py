"""One live status line for a headless `dyno run` on a terminal: state, point n/~N, speeds, ETA.

Only on a terminal (both stdout and stderr), never with --json or through a pipe: the line is rewritten
in place on stderr and erased before the results are printed.  It rides on the poller's listener (called
on every poll) and redraws at most every ``period_s`` of wall time, so it adds no timer to the run's loop
and cannot change what the run measures.

The ETA is an estimate (:func:`estimate`): a test walks the secondary speed down to
``plan.min_secondary_rpm``; the recent speed drop and wall time per point extrapolate the rest, and
:func:`eta_now` counts it down between points.  The live UI (``dyno ui``) shows the same figures.
"""

from __future__ import annotations

import math
import sys
import time

WIDTH = 79  # one line of an 80-column terminal


def estimate(rpm_secondary: list, wall_s: list, stop_rpm: float, target_points: int,
             recent: int = 3) -> tuple[int | None, float | None]:
    """(estimated total points, wall seconds left) from the points so far; (None, None) while too early.

    ``rpm_secondary[k]`` / ``wall_s[k]``: each point's secondary speed and the wall time it arrived.  The
    remaining points are the speed still to shed (down to ``stop_rpm``) over the recent speed drop per point,
    blended, over the first 8 points, from the plan's ``target_points`` (the controller adapts its brake
    step to land near it, but the first points drop speed unevenly); each takes the recent wall time per point.
    """
    n = len(rpm_secondary)
    if n < 2 or len(wall_s) != n:
        return None, None
    k = min(recent, n - 1)
    drop_per_point = (rpm_secondary[-1 - k] - rpm_secondary[-1]) / k
    wall_per_point = (wall_s[-1] - wall_s[-1 - k]) / k
    by_plan = max(target_points - n, 0)
    by_speed = (rpm_secondary[-1] - stop_rpm) / drop_per_point if drop_per_point > 0 else by_plan
    if not (math.isfinite(by_speed) and math.isfinite(wall_per_point)):
        return None, None
    w = min(1.0, (n - 1) / 8.0)
    left = max(0.0, (1.0 - w) * by_plan + w * by_speed)
    return n + round(left), left * max(wall_per_point, 0.0)


def eta_now(points: list, point_wall_s: list, now_wall_s: float, plan) -> tuple[int | None, float | None]:
    """(estimated total points, wall seconds left now): :func:`estimate` at the last point, counted down
    since.  ``point_wall_s[k]``: the wall (or loop) time point ``k`` arrived.  The headless status line and the
    live UI both show this."""
    total, eta = estimate([p.get("rpm_secondary", math.nan) for p in points], point_wall_s,
                          plan.min_secondary_rpm, plan.target_points)
    if eta is not None and point_wall_s:
        eta = max(0.0, eta - max(0.0, now_wall_s - point_wall_s[-1]))
    return total, eta


def points_text(n_points: int, total: int | None) -> str:
    return f"point {n_points}/~{total}" if total else f"point {n_points}"


def eta_text(eta_s: float | None) -> str:
    return f"ETA {_dur(eta_s)}" if eta_s is not None else "ETA —"


def _dur(s: float) -> str:
    s = int(round(s))
    return f"{s // 60}:{s % 60:02d}" if s >= 60 else f"{s} s"


def status_line(state: str, n_points: int, total: int | None, rpm_engine: float, rpm_secondary: float,
                elapsed_s: float, eta_s: float | None) -> str:
    """The text of the line (no control characters), at most WIDTH characters."""
    pts = points_text(n_points, total)
    eta = eta_text(eta_s)
    # most wanted first: what it is doing, how far, how long to go (a narrow terminal cuts the speeds)
    line = (f"{state.upper():<8} {pts:<13} {eta:<10} ran {_dur(elapsed_s):<6} "
            f"engine/secondary {rpm_engine:.0f}/{rpm_secondary:.0f} rpm")
    return line[:WIDTH]


class TtyProgress:
    """Attach with ``RunOptions.setup = progress.attach``; call :meth:`finish` before printing results."""

    def __init__(self, stream=None, *, wall_clock=time.monotonic, period_s: float = 0.25) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.wall = wall_clock
        self.period_s = period_s
        self.ctx = None
        self._t0 = self._next = 0.0
        self._point_wall_s: list = []  # wall time each point was first seen
        self.drawn = 0  # how many times the line was drawn (for tests)

    def attach(self, ctx) -> None:
        self.ctx = ctx
        self._t0 = self.wall()
        ctx.poller.listeners.append(self._on_poll)

    def _on_poll(self, events, now_s) -> None:
        t = self.wall()
        if t < self._next:
            return
        self._next = t + self.period_s
        self.draw(t)

    def line(self, t: float) -> str:
        from dyno.protocol import v1

        c, poller = self.ctx.controller, self.ctx.poller
        pts = c.points
        while len(self._point_wall_s) < len(pts):
            self._point_wall_s.append(t)
        total, eta = eta_now(pts, self._point_wall_s, t, c.plan)
        return status_line(c.state.value, len(pts), total, poller.rpm(v1.CH_PRIMARY), poller.rpm(v1.CH_SECONDARY),
                           t - self._t0, eta)

    def draw(self, t: float) -> None:
        try:
            self.stream.write("\r" + self.line(t) + "\x1b[K")
            self.stream.flush()
            self.drawn += 1
        except (OSError, ValueError):  # the terminal went away: the run goes on, silently
            self.period_s = math.inf

    def finish(self) -> None:
        """Erase the line (the results are printed where it was)."""
        if self.drawn:
            try:
                self.stream.write("\r\x1b[K")
                self.stream.flush()
            except (OSError, ValueError):
                pass


def wanted(json_output: bool) -> bool:
    """A person is watching: stdout and stderr are a terminal and the output is not JSON."""
    try:
        return not json_output and sys.stdout.isatty() and sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False
