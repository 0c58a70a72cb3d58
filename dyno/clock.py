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
import time


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
            return self._inner.select(None)
        if timeout > 0:
            if self._loop.speed:
                time.sleep(timeout / self._loop.speed)  # paced: N x real time
            self._loop.advance(timeout)
        return []


class VirtualTimeLoop(asyncio.SelectorEventLoop):
    """An asyncio loop on a virtual clock (seconds, starting at ``start_s``)."""

    def __init__(self, start_s: float = 0.0, speed: float | None = None) -> None:
        self._virtual_s = float(start_s)
        self.speed = speed  # None: as fast as possible; N: paced at N x real time
        super().__init__(selector=_VirtualSelector(self))

    def time(self) -> float:  # asyncio's clock
        return self._virtual_s

    def advance(self, dt_s: float) -> None:
        self._virtual_s += dt_s


def run(main, *, virtual: bool, start_s: float = 0.0, speed: float | None = None):
    """Run coroutine ``main`` on a virtual-time loop (optionally paced) or a real one."""
    factory = (lambda: VirtualTimeLoop(start_s, speed)) if virtual else None
    with asyncio.Runner(loop_factory=factory) as runner:
        return runner.run(main)
