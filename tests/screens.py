"""What a test reads off a screen: Textual's rendered rows (``run_test``), or a real terminal (tmux)."""

from __future__ import annotations

import os
import subprocess
import time
import uuid

from tests import processes

# A program's first frame can take a while on a loaded 2-core machine (imports, the simulated rig's set-up);
# a wait on the screen counts from that first frame, and this only bounds a program that never draws.
FIRST_FRAME_LIMIT_S = 240.0


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


class Terminal:
    """One program in a real terminal: a tmux server of its own (``tmux -L SOCKET``), one window of ``size``.

    Every process in it carries ``DYNO_TEST_TERMINAL=SOCKET`` in its environment, so :meth:`close` finds them
    all (re-parented or not) and ends them: the server first (the programs see the terminal hang up, as when
    an SSH link drops), then SIGKILL for whatever outlives ``grace_s``.  Use it through the ``terminal``
    fixture (tests/conftest.py), whose finaliser closes it whether the test passed or failed.
    """

    def __init__(self, command: str, *, size=(80, 24), cwd=None, env: dict | None = None) -> None:
        from dyno.model.cache_keys import default_cache_dir

        self.socket = f"dyno-test-{uuid.uuid4().hex[:12]}"
        self.command = command
        full_env = {"TERM": "xterm-256color", "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
                    "HOME": os.environ.get("HOME", "/tmp")}
        for name in ("DYNO_RUNS_DIR", processes.SUITE_MARK):
            if os.environ.get(name):
                full_env[name] = os.environ[name]
        # the belt table the session built (tests/conftest.py), not a rebuild in a fresh HOME's cache
        full_env["DYNO_MODEL_CACHE"] = os.environ.get("DYNO_MODEL_CACHE", str(default_cache_dir()))
        full_env.update(env or {})
        full_env[processes.TERMINAL_MARK] = self.socket
        self._first_frame_at: float | None = None
        self.closed = False
        self.killed = ""  # what :meth:`close` had to SIGKILL (a program that ignored the hang-up), described
        args = ["new-session", "-d", "-x", str(size[0]), "-y", str(size[1]), "-s", "main"]
        if cwd is not None:
            args += ["-c", str(cwd)]
        subprocess.run(["tmux", "-L", self.socket, "-f", "/dev/null", *args, command], check=True, timeout=20,
                       env=full_env)

    def tmux(self, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run(["tmux", "-L", self.socket, *args], capture_output=True, text=True, timeout=20)

    def keys(self, *keys: str) -> None:
        self.tmux("send-keys", "-t", "main", *keys)

    def screen(self) -> str:
        return self.tmux("capture-pane", "-p", "-t", "main").stdout

    def processes(self) -> list[int]:
        """The live processes started in this terminal (the tmux server included)."""
        return processes.marked(processes.TERMINAL_MARK, self.socket)

    def _await_first_frame(self) -> None:
        if self._first_frame_at is not None:
            return
        t_end = time.monotonic() + FIRST_FRAME_LIMIT_S
        while time.monotonic() < t_end and not self.screen().strip():
            time.sleep(0.2)
        self._first_frame_at = time.monotonic()

    def wait(self, needles, timeout_s: float, poll_s: float = 0.3) -> str:
        """The screen once it shows every one of ``needles``, within ``timeout_s`` of the program's first frame
        (or of this call, when that came earlier).  Fails at once if the program exited (the shell line after it
        printed ``EXITED=``) unless that is what is awaited."""
        needles = [needles] if isinstance(needles, str) else list(needles)
        self._await_first_frame()
        t_end = time.monotonic() + timeout_s
        screen = ""
        while time.monotonic() < t_end:
            screen = self.screen()
            if all(n in screen for n in needles):
                return screen
            if "EXITED=" in screen and not any("EXITED=" in n for n in needles):
                break  # the program is gone (a start-up crash): fail now, with what it printed
            time.sleep(poll_s)
        missing = [n for n in needles if n not in screen]
        raise AssertionError(f"waited {timeout_s} s (from the first frame) for {missing!r} on the screen of "
                             f"`{self.command}`; the program exited or never showed it:\n{screen}")

    def hang_up(self) -> None:
        """Close the terminal (tmux kill-server): its programs get SIGHUP, as when the SSH link drops."""
        self.tmux("kill-server")

    def close(self, grace_s: float = 20.0) -> list[int]:
        """Hang up, wait up to ``grace_s`` for every process of the terminal to end, SIGKILL the rest; those
        killed (an empty list when everything ended by itself)."""
        if self.closed:
            return []
        self.closed = True
        self.hang_up()
        left = processes.wait_gone(self.processes, grace_s)
        self.killed = processes.describe(left)
        processes.kill(left)
        return left


def pids_matching(marker: str) -> list[int]:
    """The processes whose command line contains ``marker`` (pgrep -f)."""
    p = subprocess.run(["pgrep", "-f", marker], capture_output=True, text=True, timeout=20)
    return [int(x) for x in p.stdout.split()]


def seconds_until_gone(pids, timeout_s: float, poll_s: float = 0.02) -> float:
    """Wall seconds until none of ``pids`` exists (``timeout_s`` if some still do; those are then killed)."""

    def alive() -> list[int]:
        return [p for p in pids if (st := processes.stat(p)) is not None and st[0] != "Z"]

    t0 = time.monotonic()
    left = processes.wait_gone(alive, timeout_s, poll_s)
    if left:
        processes.kill(left)  # do not leave it behind for the next test
        return timeout_s
    return time.monotonic() - t0
