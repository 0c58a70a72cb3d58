"""Injected time.

Everything in dyno reads time from the running asyncio loop (``loop.time()``)
or from a ``now_s`` callable passed in.  On the rig that is the ordinary loop
(monotonic clock).  In simulations and tests it is :class:`VirtualTimeLoop`:
an ordinary selector event loop whose clock only moves when every task is
waiting, jumping straight to the next timer.  ``asyncio.sleep``, ``wait_for``
and ``call_later`` keep their meaning, so the same coroutines run faster than
real time and deterministically, with no test-only code paths.
"""

from __future__ import annotations

import asyncio
import selectors
import threading
import time


# --- clocks for code that is not on a loop (hardware adapters, the watchdog thread) ----------
# Everything time-based on the rig (brake steps, relay settle, release stroke, reset pulse,
# watchdog) reads ``clock.now()`` and waits with ``clock.sleep()``, so tests swap in
# :class:`FakeClock` and an 8 s release stroke takes no time.  They live here, below
# every layer that uses them (transports and hw alike).

class MonotonicClock:
    """Real time: ``time.monotonic`` (never jumps with NTP on the Pi)."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class FakeClock:
    """Time that only moves when someone sleeps (or calls :meth:`advance`).

    ``on_sleep(clock, seconds)`` (optional) runs before each sleep; tests use it
    to throw an exception or deliver a signal part-way through a step.
    """

    def __init__(self, start_s: float = 1000.0, on_sleep=None) -> None:
        self._t = float(start_s)
        self._lock = threading.Lock()
        self.on_sleep = on_sleep
        self.slept_s: list[float] = []

    def now(self) -> float:
        with self._lock:
            return self._t

    def advance(self, seconds: float) -> None:
        with self._lock:
            self._t += max(0.0, float(seconds))

    def sleep(self, seconds: float) -> None:
        if self.on_sleep is not None:
            self.on_sleep(self, seconds)
        self.slept_s.append(seconds)
        self.advance(seconds)


class Pace:
    """A virtual loop paced at ``speed`` x real time against a wall-clock anchor.

    Each wait for the next timer sleeps until the wall instant at which the loop's virtual clock is due
    there (anchor + virtual elapsed / speed), not for the timeout itself: the work done between waits
    does not add to the pace (sleeping each whole timeout after the work would lag real time by the work's
    share), and a loop that fell behind
    catches up as a real one is on time again after a late tick.  A debt over ``MAX_DEBT_S`` is written
    off (the anchor moves: real time lost, as a real loop's poller skips ticks).  Each wake-up's lateness
    past its deadline is kept (a 20 us histogram): the wall-clock jitter a real-time loop would have had.
    """

    BIN_S = 20e-6
    MAX_DEBT_S = 0.1

    def __init__(self, speed: float) -> None:
        self.speed = float(speed)
        self.anchor: tuple[float, float] | None = None  # (wall s, virtual s) that the deadlines count from
        self.started: tuple[float, float] | None = None  # (wall s, virtual s) of the first paced wait
        self.late: dict[int, int] = {}
        self.late_max_s = 0.0
        self.wakes = 0
        self.written_off_s = 0.0

    def wait(self, virtual_s: float, timeout_s: float) -> None:
        now = time.monotonic()
        if self.anchor is None:
            self.anchor = (now, virtual_s)
            if self.started is None:
                self.started = self.anchor
        deadline = self.anchor[0] + (virtual_s + timeout_s - self.anchor[1]) / self.speed
        if deadline > now:
            time.sleep(deadline - now)
            now = time.monotonic()
        late = now - deadline
        self.wakes += 1
        b = int(late / self.BIN_S + 0.5)
        self.late[b] = self.late.get(b, 0) + 1
        if late > self.late_max_s:
            self.late_max_s = late
        if late > self.MAX_DEBT_S:
            self.written_off_s += late
            self.anchor = (now, virtual_s + timeout_s)

    def stats(self, virtual_s: float) -> dict | None:
        """``held``: virtual seconds per wall second / speed since the first wait (1.0: the pace kept); the
        wake-ups' lateness p99 and max (ms); the debt written off (s)."""
        if self.started is None:
            return None
        wall_s = time.monotonic() - self.started[0]
        rig_s = virtual_s - self.started[1]
        n, cum, p99 = sum(self.late.values()), 0, 0.0
        for b in sorted(self.late):
            cum += self.late[b]
            if cum >= 0.99 * n:
                p99 = min(b * self.BIN_S, self.late_max_s)  # (the bin's upper edge can pass the exact max)
                break
        return {"speed": self.speed, "wall_s": round(wall_s, 3), "rig_s": round(rig_s, 3),
                "held": round(rig_s / (wall_s * self.speed), 4) if wall_s > 0 else None, "wakes": self.wakes,
                "late_p99_ms": round(p99 * 1e3, 3), "late_max_ms": round(self.late_max_s * 1e3, 3),
                "written_off_s": round(self.written_off_s, 3)}


class _VirtualSelector(selectors.BaseSelector):
    """Wraps a real selector; a wait with nothing ready advances virtual time."""

    def __init__(self, loop: "VirtualTimeLoop") -> None:
        self._inner = selectors.DefaultSelector()
        self._loop = loop

    def register(self, fileobj, events, data=None):
        return self._inner.register(fileobj, events, data)

    def unregister(self, fileobj):
        return self._inner.unregister(fileobj)

    def modify(self, fileobj, events, data=None):
        return self._inner.modify(fileobj, events, data)

    def get_map(self):
        return self._inner.get_map()

    def close(self):
        self._inner.close()

    def select(self, timeout=None):
        ready = self._inner.select(0)
        if ready:
            return ready
        if timeout is None:
            # Nothing scheduled and nothing ready: only real I/O (a thread
            # finishing, a signal) can wake us; wait for it in real time.
            ready = self._inner.select(None)
            if self._loop.pace is not None:  # (real time passed that is no rig time: not a debt to catch up)
                self._loop.pace.anchor = None
            return ready
        if timeout > 0:
            if self._loop.pace is not None:
                self._loop.pace.wait(self._loop.time(), timeout)  # paced: N x real time
            self._loop.advance(timeout)
        return []


class VirtualTimeLoop(asyncio.SelectorEventLoop):
    """An asyncio loop on a virtual clock (seconds, starting at ``start_s``).

    *Background tickers* stand for OS threads (the safety watchdog): they run on
    the same clock but not on the loop, so they keep running while a callback
    blocks the loop.  :meth:`advance` calls each one at its period boundaries,
    whoever advances the clock (the idle selector, or :meth:`block` simulating a
    callback that hogs the loop).
    """

    def __init__(self, start_s: float = 0.0, speed: float | None = None) -> None:
        self._virtual_s = float(start_s)
        self.speed = speed  # None: as fast as possible; N: paced at N x real time
        self.pace = Pace(speed) if speed else None
        self._tickers: list[list] = []  # [next_due_s, period_s, fn]
        self.blocked = False  # inside :meth:`block`: a callback holds the loop (threads run on)
        super().__init__(selector=_VirtualSelector(self))

    def time(self) -> float:  # asyncio's clock
        return self._virtual_s

    def add_ticker(self, fn, period_s: float):
        """Call ``fn()`` every ``period_s`` of virtual time, even while the loop is blocked."""
        entry = [self._virtual_s + period_s, float(period_s), fn]
        self._tickers.append(entry)
        return entry

    def remove_ticker(self, entry) -> None:
        if entry in self._tickers:
            self._tickers.remove(entry)

    def advance(self, dt_s: float) -> None:
        end = self._virtual_s + dt_s
        tickers = self._tickers
        while tickers:
            entry = min(tickers, key=lambda e: e[0])
            if entry[0] > end:
                break
            self._virtual_s = max(self._virtual_s, entry[0])
            entry[0] += entry[1]
            entry[2]()
        self._virtual_s = end

    def block(self, dt_s: float) -> None:
        """Simulate a callback that holds the loop for ``dt_s`` (drill ``loop-stall``)."""
        if self.speed:
            time.sleep(dt_s / self.speed)
        self.blocked = True
        try:
            self.advance(dt_s)
        finally:
            self.blocked = False

    def pace_stats(self) -> dict | None:
        """A paced loop's pace as held so far (:meth:`Pace.stats`); None when it runs as fast as it can."""
        return self.pace.stats(self._virtual_s) if self.pace is not None else None


def freeze_host(loop, dt_s: float, world, chunk_s: float = 0.005) -> None:
    """The whole host stops for ``dt_s`` (drill ``pi-freeze``): no callback, no background ticker (the
    watchdog thread) runs, while ``world()`` — the simulated physics and the Nano — is stepped every
    ``chunk_s`` on the clock.  Tickers due meanwhile run when the loop advances next (the host resumes)."""
    if not isinstance(loop, VirtualTimeLoop):
        raise RuntimeError("pi-freeze needs the simulated rig's virtual clock")
    end = loop._virtual_s + dt_s
    if loop.speed:
        time.sleep(dt_s / loop.speed)
        if loop.pace is not None:  # (frozen wall time is no debt to catch up)
            loop.pace.anchor = None
    while loop._virtual_s < end:
        loop._virtual_s = min(end, loop._virtual_s + chunk_s)
        world()


def block_loop(loop, dt_s: float) -> None:
    """Hold ``loop`` for ``dt_s``: virtual loops advance their clock, real ones really block."""
    if isinstance(loop, VirtualTimeLoop):
        loop.block(dt_s)
    else:
        time.sleep(dt_s)


class LoopClock:
    """``now()`` of a loop's clock, for code that is not on the loop (the watchdog)."""

    def __init__(self, loop) -> None:
        self._loop = loop

    def now(self) -> float:
        return self._loop.time()

    def sleep(self, dt_s: float) -> None:
        time.sleep(dt_s)


class LoopRigClock:
    """Rig time on the running loop's own clock: the rig, and a simulation on a (virtual) loop.

    The controller's clock for everything the plan times (``now()`` in rig seconds, ``await sleep(rig_s)``);
    a paced live session gives it :class:`dyno.session.pacing.ScaledClock` instead (the same pair at
    ``speed`` x the loop's rate).  The safety deadlines never use it: they stay on the loop's clock.
    """

    speed = 1.0

    def now(self) -> float:
        return asyncio.get_running_loop().time()

    async def sleep(self, rig_s: float) -> None:
        await asyncio.sleep(rig_s)


LOOP_RIG_CLOCK = LoopRigClock()


def run(main, *, virtual: bool, start_s: float = 0.0, speed: float | None = None):
    """Run coroutine ``main`` on a virtual-time loop (optionally paced) or a real one."""
    factory = (lambda: VirtualTimeLoop(start_s, speed)) if virtual else None
    with asyncio.Runner(loop_factory=factory) as runner:
        return runner.run(main)
