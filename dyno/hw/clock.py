"""Injectable time for the hardware layer.

Everything time-based on the rig (brake steps, relay settle, release stroke,
reset pulse, watchdog) reads ``clock.now()`` and waits with ``clock.sleep()``,
so tests swap in :class:`FakeClock` and an 8 s release stroke takes no time.
"""

from __future__ import annotations

import threading
import time


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
