"""One live status line for a headless `dyno run` on a terminal: state, point n/~N, speeds, ETA.

Only on a terminal (both stdout and stderr), never with --json or through a pipe: the line is rewritten
in place on stderr and erased before the results are printed.  It rides on the poller's listener (called
on every poll) and redraws at most every ``period_s`` of wall time, so it adds no timer to the run's loop
and cannot change what the run measures.

The ETA is an estimate (:mod:`dyno.control.progress`); the live UI (``dyno ui``) and the web view show the
same figures.
"""

from __future__ import annotations

import math
import sys
import time

from dyno.control.progress import duration_text, eta_now, eta_text, points_text

WIDTH = 79  # one line of an 80-column terminal


def status_line(state: str, n_points: int, total: int | None, rpm_engine: float, rpm_secondary: float,
                elapsed_s: float, eta_s: float | None) -> str:
    """The text of the line (no control characters), at most WIDTH characters."""
    pts = points_text(n_points, total)
    eta = eta_text(eta_s)
    # most wanted first: what it is doing, how far, how long to go (a narrow terminal cuts the speeds)
    line = (f"{state.upper():<8} {pts:<13} {eta:<10} ran {duration_text(elapsed_s):<6} "
            f"engine/secondary {rpm_engine:.0f}/{rpm_secondary:.0f} rpm")
    return line[:WIDTH]


class TtyProgress:
    """Attach with ``RunSpec(setup=progress.attach)``; call :meth:`finish` before printing results."""

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
