"""The rig's side of the live view: a poller listener that copies the live values into a bounded queue.

It runs on the rig's loop, so it does as little as it can: a wall-clock check on every poll, and at most
``rate_hz`` times a second (and at once on a state change or an abort) one snapshot of plain numbers
(:mod:`dyno.web.snapshot`) put into a ``queue.Queue`` of a few frames without waiting: when the server's
thread has not taken them, the oldest is dropped.  Nothing here waits on the server, a socket or a lock
held by the server for longer than a queue operation; an error in it is counted, never raised into the
poller.
"""

from __future__ import annotations

import queue
import time

from dyno.web.snapshot import SnapshotBuilder


class RunSource:
    """What ``dyno run`` shows: its context on a (virtual, paced) loop."""

    def __init__(self, ctx, loop, speed: float | None) -> None:
        self.ctx, self.loop, self.speed = ctx, loop, speed or 1.0

    @property
    def poller(self):
        return self.ctx.poller

    @property
    def controller(self):
        return self.ctx.controller

    def progress(self):
        from dyno.control.progress import eta_now

        c = self.ctx.controller
        pts = c.points
        ends = [p.get("host_t_end_s", float("nan")) for p in pts]
        total, eta = eta_now(pts, ends, self.loop.time(), c.plan)
        return len(pts), total, (eta / self.speed if eta is not None else None)  # loop seconds -> wall

    def rig_safe(self):
        return _is_safe(self.ctx)

    def run_dir(self):
        return str(self.ctx.writer.run_dir)

    def t_sim_s(self):
        return self.loop.time()

    def estop(self, source: str) -> None:
        self.ctx.controller.estop(source)


class SessionSource:
    """What ``dyno ui`` shows: its live session (a re-arm swaps the controller; this follows it)."""

    def __init__(self, session) -> None:
        self.session = session

    @property
    def poller(self):
        return self.session.poller

    @property
    def controller(self):
        return self.session.controller

    def progress(self):
        return self.session.test_progress()

    def rig_safe(self):
        return _is_safe(self.session.ctx)

    def run_dir(self):
        return str(self.session.ctx.writer.run_dir)

    def t_sim_s(self):
        return self.session.sim_now()

    def estop(self, source: str) -> None:
        self.session.estop(source)  # the E-STOP key's path


def _is_safe(ctx):
    """The physics' safe state on the simulated rig (pads off, engine killed, throttle idle); None on the
    real rig, where the host only knows what it commanded."""
    if ctx.sim is None:
        return None
    try:
        return bool(ctx.sim.actuators.is_safe)
    except Exception:  # noqa: BLE001  a display value: never an error in the poller
        return None


class LiveFeed:
    """Attach with :meth:`attach`; the server takes frames from :attr:`frames` (a bounded queue)."""

    def __init__(self, source, *, rate_hz: float = 10.0, queue_size: int = 4, wall=time.monotonic) -> None:
        self.source = source
        self.period_s = 1.0 / rate_hz
        self.frames: queue.Queue = queue.Queue(maxsize=queue_size)
        self.wall = wall
        self.builder = SnapshotBuilder()
        self._next_s = 0.0
        self._seen = None  # (state, aborts) of the last frame: a change is published at once
        self.published = self.dropped = self.errors = 0
        self.last_error: str | None = None
        self.loop = None

    def attach(self, loop) -> None:
        self.loop = loop
        self.source.poller.listeners.append(self.on_poll)

    def detach(self) -> None:
        try:
            self.source.poller.listeners.remove(self.on_poll)
        except ValueError:
            pass

    def on_poll(self, events, now_s: float) -> None:
        t = self.wall()
        c = self.source.controller
        seen = (c.state, len(c.aborts), len(c.points))
        if t < self._next_s and seen == self._seen:
            return
        self._next_s, self._seen = t + self.period_s, seen
        try:
            self.put(self.snapshot(now_s))
        except Exception as exc:  # noqa: BLE001  a broken frame costs the page a frame, never the poller
            self.errors += 1
            self.last_error = f"{type(exc).__name__}: {exc}"

    def snapshot(self, now_s: float, **extra) -> dict:
        s = self.source
        snap = self.builder.build(s.poller, s.controller, now_s, progress=s.progress(), rig_safe=s.rig_safe(),
                                  run_dir=s.run_dir(), t_sim_s=s.t_sim_s())
        snap.update(extra)
        return snap

    def put(self, snap: dict) -> None:
        """Into the queue without waiting: a full queue loses its oldest frame."""
        while True:
            try:
                self.frames.put_nowait(snap)
                self.published += 1
                return
            except queue.Full:
                try:
                    self.frames.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass

    def final(self, result: dict) -> None:
        """The ended run's last frame: the run's own verdict on the rig's safety (dyno run's ``rig_safe``:
        the physical outputs after the release stroke)."""
        try:
            snap = self.snapshot(self.loop.time() if self.loop is not None else 0.0, ended=True)
        except Exception:  # noqa: BLE001  (the loop is closed: the last values are what the result says)
            snap = {"state": result.get("state"), "points": [], "ended": True}
        snap["rig_safe"] = result.get("rig_safe", snap.get("rig_safe"))
        if result.get("rig_unsafe_because"):
            snap["rig_unsafe_because"] = result["rig_unsafe_because"]
        if result.get("aborts"):
            a = result["aborts"][-1]
            snap["abort_cause"], snap["abort_detail"] = a.get("cause"), a.get("detail")
        self.put(snap)

    def request_stop(self, source: str = "web page STOP") -> bool:
        """From the server's thread: the E-STOP key's abort, run on the rig's loop."""
        if self.loop is None or self.loop.is_closed():
            return False
        self.loop.call_soon_threadsafe(self.source.estop, source)
        return True
