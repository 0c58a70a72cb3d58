"""The run's progress: how many points a test will take and how long is left, from the points so far.

Pure (no I/O, times passed in).  The headless status line (:mod:`dyno.cli.progress`), the live UI and the web
view all show these figures.  A test walks the secondary speed down to ``plan.min_secondary_rpm``; the recent
speed drop and wall time per point extrapolate the rest (:func:`estimate`), and :func:`eta_now` counts it
down between points.
"""

from __future__ import annotations

import math


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
    return f"ETA {duration_text(eta_s)}" if eta_s is not None else "ETA —"


def duration_text(s: float) -> str:
    s = int(round(s))
    return f"{s // 60}:{s % 60:02d}" if s >= 60 else f"{s} s"
