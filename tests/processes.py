"""Which processes the test suite started, found by an environment mark they inherit.

Every process a test starts inherits ``DYNO_TEST_SUITE`` (set once per pytest run, see tests/conftest.py), and
every process in a test's terminal also ``DYNO_TEST_TERMINAL`` (its own tmux socket). A process keeps the
environment it started with in ``/proc/PID/environ`` even after its parent died and it was re-parented, so a
mark finds the strays a parent-child walk misses (a tmux server detaches from the test that started it).
"""

from __future__ import annotations

import os
import signal
import time

SUITE_MARK = "DYNO_TEST_SUITE"
TERMINAL_MARK = "DYNO_TEST_TERMINAL"


def _environ(pid: int) -> bytes:
    try:
        with open(f"/proc/{pid}/environ", "rb") as f:
            return f.read()
    except OSError:
        return b""


def stat(pid: int) -> tuple[str, int] | None:
    """(state letter, parent pid), or None when the process is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            rest = f.read().rsplit(") ", 1)[1].split()
        return rest[0], int(rest[1])
    except (OSError, IndexError, ValueError):
        return None


def cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace").strip()
    except OSError:
        return ""


def marked(name: str, value: str, exclude=()) -> list[int]:
    """Live (not zombie) processes whose environment holds ``name=value``, except ``exclude``."""
    needle = f"{name}={value}".encode() + b"\0"
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        pid = int(entry)
        if pid in exclude or pid == os.getpid():
            continue
        st = stat(pid)
        if st is None or st[0] == "Z":
            continue
        env = _environ(pid)
        if env.startswith(needle) or b"\0" + needle in env:
            found.append(pid)
    return found


def children_of(pid: int) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            st = stat(int(entry))
            if st is not None and st[1] == pid:
                out.append(int(entry))
    return out


def describe(pids) -> str:
    return "; ".join(f"{p}: {cmdline(p)[:160]}" for p in pids)


def wait_gone(find, timeout_s: float, poll_s: float = 0.05) -> list[int]:
    """Poll ``find()`` until it returns nothing or ``timeout_s`` passes; what is still alive then."""
    t_end = time.monotonic() + timeout_s
    alive = find()
    while alive and time.monotonic() < t_end:
        time.sleep(poll_s)
        alive = find()
    return alive


def kill(pids) -> None:
    for p in pids:
        try:
            os.kill(p, signal.SIGKILL)
        except OSError:
            pass


# Helpers a Python process starts for itself and keeps for its lifetime, not a test's doing.
_PROCESS_HELPERS = ("multiprocessing.resource_tracker", "multiprocessing.forkserver")


def descendants(pid: int, owned_by_others=frozenset()) -> set[int]:
    """Every live process below ``pid`` (children, their children, ...), Python's own helpers left out, and
    not looking below the processes in ``owned_by_others`` (what they start is theirs: a browser's renderers)."""
    parent_of = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            st = stat(int(entry))
            if st is not None and st[0] != "Z":
                parent_of[int(entry)] = st[1]
    found: set[int] = set()
    frontier = {pid}
    while frontier:
        frontier = {p for p, pp in parent_of.items() if pp in frontier and p not in found}
        found |= frontier
        frontier -= set(owned_by_others)
    return {p for p in found if not any(h in cmdline(p) for h in _PROCESS_HELPERS)}
