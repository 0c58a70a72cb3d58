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
