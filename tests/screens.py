"""What a test reads off a screen: Textual's rendered rows (``run_test``), or a tmux pane (a real terminal)."""

from __future__ import annotations

import subprocess
import time


def screen_text(app) -> str:
    """The rendered screen as plain text, one line per row (a structural snapshot)."""
    return "\n".join(strip.text for strip in app.screen._compositor.render_strips())


async def wait_for(pilot, cond, timeout_s: float, step_s: float = 0.2) -> bool:
    """Let a ``run_test`` app run until ``cond()`` holds (True) or ``timeout_s`` passes (False)."""
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if cond():
            return True
        await pilot.pause(step_s)
    return cond()


def tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], capture_output=True, text=True, timeout=20).stdout


def pane(session: str) -> str:
    return tmux("capture-pane", "-p", "-t", session)


def wait_screen(session: str, needles, timeout_s: float, poll_s: float = 0.3) -> str:
    """The pane once it shows every one of ``needles``; fails at once if the program exited (the shell line
    after it printed ``EXITED=``) unless that is what is awaited."""
    needles = [needles] if isinstance(needles, str) else list(needles)
    t_end = time.monotonic() + timeout_s
    screen = ""
    while time.monotonic() < t_end:
        screen = pane(session)
        if all(n in screen for n in needles):
            return screen
        if "EXITED=" in screen and not any("EXITED=" in n for n in needles):
            break  # the program is gone (a start-up crash): fail now, with what it printed
        time.sleep(poll_s)
    raise AssertionError(f"{needles!r} not on screen (waited up to {timeout_s} s or the program exited):\n{screen}")


def pids_matching(marker: str) -> list[int]:
    """The processes whose command line contains ``marker`` (pgrep -f)."""
    p = subprocess.run(["pgrep", "-f", marker], capture_output=True, text=True, timeout=20)
    return [int(x) for x in p.stdout.split()]


def seconds_until_gone(pids, timeout_s: float, poll_s: float = 0.02) -> float:
    """Wall seconds until none of ``pids`` exists (``timeout_s`` if some still do; those are then killed)."""
    import os

    def alive(pid: int) -> bool:
        try:
            with open(f"/proc/{pid}/stat") as f:
                return f.read().split(") ", 1)[1][:1] != "Z"  # a zombie has ended: only its parent's wait is left
        except (OSError, IndexError):
            return False

    t0 = time.monotonic()
    while any(alive(p) for p in pids) and time.monotonic() - t0 < timeout_s:
        time.sleep(poll_s)
    dt = time.monotonic() - t0
    for p in pids:
        if alive(p):
            try:
                os.kill(p, 9)  # do not leave it behind for the next test
            except OSError:
                pass
            dt = timeout_s
    return dt
