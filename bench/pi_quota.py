"""CPU quotas for bench/bench_pi_budget.py: cgroup v1 ``cpu`` groups with a short CFS period.

A group's processes together get ``fraction`` x one core: ``cpu.cfs_period_us`` = 10,000 and
``cpu.cfs_quota_us`` = fraction x 10,000 (2,500 us for a quarter).  A short period is what a slow CPU looks
like to a real-time loop: a process that has used its 2.5 ms waits up to 7.5 ms, never the hundreds of ms a
100 ms period could make it wait.  Needs root and a writable cgroup v1 ``cpu`` hierarchy
(``/sys/fs/cgroup/cpu``); :func:`why_not_writable` says why not, in one line.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

CG_ROOT = Path(os.environ.get("DYNO_BENCH_CGROUP_CPU", "/sys/fs/cgroup/cpu"))
PERIOD_US = 10_000


def why_not_writable() -> str | None:
    """None when a child group can be made and given a quota here; else the reason."""
    if not (CG_ROOT / "cpu.cfs_quota_us").is_file():
        return f"no cgroup v1 cpu controller at {CG_ROOT}"
    probe = CG_ROOT / f"dyno-pi-probe-{os.getpid()}"
    try:
        probe.mkdir()
        try:
            (probe / "cpu.cfs_period_us").write_text(str(PERIOD_US))
            (probe / "cpu.cfs_quota_us").write_text(str(PERIOD_US // 4))
        finally:
            probe.rmdir()
    except OSError as exc:
        return f"{CG_ROOT}: {exc.strerror or exc}"
    return None


class Quota:
    """One child group of ``fraction`` of a core (``fraction`` >= 1: no quota, the group only counts)."""

    def __init__(self, name: str, fraction: float) -> None:
        self.fraction = fraction
        self.path = CG_ROOT / f"dyno-pi-{name}-{os.getpid()}"
        self.path.mkdir(exist_ok=True)
        (self.path / "cpu.cfs_period_us").write_text(str(PERIOD_US))
        quota = -1 if fraction >= 1.0 else max(1000, round(fraction * PERIOD_US))
        (self.path / "cpu.cfs_quota_us").write_text(str(quota))
        self._stat0 = self.stat()

    @property
    def procs(self) -> Path:
        return self.path / "cgroup.procs"

    def add(self, pid: int) -> bool:
        try:
            self.procs.write_text(str(pid))
            return True
        except OSError:  # (gone already)
            return False

    def stat(self) -> dict:
        out = {}
        for line in (self.path / "cpu.stat").read_text().splitlines():
            k, _, v = line.partition(" ")
            out[k] = int(v)
        return out

    def throttled(self) -> dict:
        """Since the group was made: CFS periods, the share of them in which the group was throttled, and
        the time it waited throttled (s)."""
        s, s0 = self.stat(), self._stat0
        periods = s.get("nr_periods", 0) - s0.get("nr_periods", 0)
        throttled = s.get("nr_throttled", 0) - s0.get("nr_throttled", 0)
        return {"periods": periods, "throttled_frac": throttled / periods if periods else 0.0,
                "throttled_s": (s.get("throttled_time", 0) - s0.get("throttled_time", 0)) / 1e9}

    def close(self) -> None:
        """Whatever is left goes back to the root group, then the group is removed."""
        for _ in range(50):
            pids = [p for p in self.procs.read_text().split() if p]
            for p in pids:
                try:
                    (CG_ROOT / "cgroup.procs").write_text(p)
                except OSError:
                    pass
            try:
                self.path.rmdir()
                return
            except OSError:
                time.sleep(0.1)


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (children, theirs, ...), from /proc."""
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(d.name))
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def in_group_argv(quota: Quota, argv: list[str]) -> list[str]:
    """``argv`` started inside ``quota``'s group: the shell joins the group, then becomes the command."""
    return ["sh", "-c", f'echo $$ > {quota.procs} && exec "$0" "$@"', *argv]
