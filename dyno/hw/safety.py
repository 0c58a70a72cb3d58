"""Getting the rig into its safe state on every way out.

Safe state = throttle idle, engine killed, brake released (enable off at once,
release stroke, then de-energised).  Paths covered:

* start-up: :class:`SafetyGuard` enters it on ``__enter__`` (the brake
  position after a crash is unknown);
* normal exit and any unhandled exception: ``__exit__`` (and ``atexit`` as a
  backstop for code that never leaves the ``with`` block cleanly);
* SIGTERM (systemd stop) and SIGINT (Ctrl-C): the handler enters the safe
  state *inside the handler*, before unwinding, then raises ``SystemExit`` so
  ``finally`` blocks and ``__exit__`` still run;
* the controller's abort: it calls ``actuators.safe_state()`` itself;
* a control loop that stops ticking: :class:`Watchdog`, as an asyncio task
  (:meth:`Watchdog.run`) or, for loops that may block the event loop itself,
  a thread (:meth:`Watchdog.start_thread`).

The waits are all on the actuators' injected clock, so tests run in no time.
"""

from __future__ import annotations

import asyncio
import atexit
import logging
import signal
import threading

from dyno.control.outputs import enter_safe_state
from dyno.clock import MonotonicClock

#: distinct look errors a watchdog keeps (each further one is counted in ``errors_dropped``)
MAX_ERRORS = 20

DEFAULT_SIGNALS = (signal.SIGTERM, signal.SIGINT)


class SafetyGuard:
    """Context manager: safe state on entry, on exit of any kind, on signals.

    >>> with SafetyGuard(actuators):     # doctest: +SKIP
    ...     run_test(actuators)
    """

    def __init__(self, actuators, *, signals=DEFAULT_SIGNALS, use_atexit: bool = True,
                 release_timeout_s: float | None = None) -> None:
        self.actuators = actuators
        self.signals = tuple(signals)
        self.use_atexit = use_atexit
        self.release_timeout_s = release_timeout_s
        self._old_handlers: dict[int, object] = {}
        self._done = False
        self.signal_received: int | None = None

    # -- the parts, public so an event-loop program can wire them itself

    def handle_signal(self, signum, frame=None) -> None:
        """Signal handler: safe state first, then unwind with exit code 128+signum."""
        self.signal_received = signum
        self.actuators.safe_state(latch=True)
        raise SystemExit(128 + int(signum))

    def install(self) -> None:
        # signal.signal only works in the main thread; elsewhere rely on __exit__/atexit.
        if threading.current_thread() is threading.main_thread():
            for sig in self.signals:
                self._old_handlers[sig] = signal.signal(sig, self.handle_signal)
        if self.use_atexit:
            atexit.register(self.shutdown)

    def uninstall(self) -> None:
        for sig, old in self._old_handlers.items():
            signal.signal(sig, old)
        self._old_handlers.clear()
        if self.use_atexit:
            atexit.unregister(self.shutdown)

    def shutdown(self) -> None:
        """Safe state, wait for the release stroke, release the pins.  Idempotent."""
        if self._done:
            return
        self._done = True
        act = self.actuators
        try:
            act.safe_state()
            finish = getattr(act, "finish_release", None)
            if finish is not None:
                finish(self.release_timeout_s)
        finally:
            close = getattr(act, "close", None)
            if close is not None:
                close()

    def __enter__(self):
        self.actuators.safe_state()
        self.install()
        return self

    def __exit__(self, exc_type, exc, tb):
        # A second Ctrl-C during the release stroke must not leave the enable
        # on: ignore further signals while shutting down.
        for sig in self.signals:
            if sig in self._old_handlers:
                signal.signal(sig, signal.SIG_IGN)
        try:
            self.shutdown()
        finally:
            self.uninstall()
        return False


class Watchdog:
    """Forces the safe state if the control loop stops ticking.

    The loop's sign of life is ``actuators.last_tick_s`` (set by
    ``tick()``) or an explicit :meth:`kick`.  Once tripped, the watchdog latches
    the safe state and keeps servicing the actuators, because with the loop
    dead nobody else would finish the release stroke.
    """

    def __init__(self, actuators, timeout_s: float, clock=None, on_trip=None, level_checks=()) -> None:
        self.actuators = actuators
        self.timeout_s = float(timeout_s)
        self.clock = clock or getattr(actuators, "clock", None) or MonotonicClock()
        self.on_trip = on_trip
        self._last_kick_s = self.clock.now()
        self.tripped = False
        # the liveness trip as the look saw it (the session's heartbeat reports it: dyno.session.safety); None
        # when it has not tripped that way (a look that raised trips it without)
        self.silent_s: float | None = None
        self.tripped_at_s: float | None = None
        self.level_checks = list(level_checks)  # callables run on every look, e.g. the E-stop input's level
        self.errors: list[str] = []  # exceptions caught inside a look (each one safed the rig; it kept watching)
        self.error_counts: dict[str, int] = {}  # how often each of them came (a stuck input: every look)
        self.errors_dropped = 0  # distinct errors beyond MAX_ERRORS (counted, not kept)
        self.log = logging.getLogger("dyno.watchdog")
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def kick(self) -> None:
        self._last_kick_s = self.clock.now()

    def last_alive_s(self) -> float:
        return max(self._last_kick_s, getattr(self.actuators, "last_tick_s", float("-inf")))

    def check(self) -> bool:
        """One watchdog look; returns True if tripped (now or before).

        It cannot die: an exception anywhere in a look (a level check's ``OSError``, a clock, a callback)
        puts the rig in its latched safe state, is logged in :attr:`errors`, and the next look runs as usual.
        """
        try:
            return self._look()
        except Exception as exc:  # noqa: BLE001 - a watchdog that stops watching is the one thing not allowed
            self._failed(exc)
            return self.tripped

    def _failed(self, exc: BaseException) -> None:
        """A look raised: latch the safe state, say so once (a failing input repeats every look: its
        count grows, not the log), keep watching.  Nothing here may raise: each step has its own guard."""
        self.tripped = True  # the loop's beat reports it (an abort record); servicing goes on
        try:
            msg = f"watchdog look failed: {type(exc).__name__}: {exc}"
        except BaseException:  # noqa: BLE001 - an exception whose str() raises
            msg = f"watchdog look failed: {type(exc).__name__}"
        try:
            enter_safe_state(self.actuators)
        except BaseException as exc2:  # noqa: BLE001 - still keep watching (the next look tries again)
            msg += f"; safe state failed too: {type(exc2).__name__}"
        try:
            self._note(msg)
        except BaseException:  # noqa: BLE001 - a log that cannot be written must not stop the watching
            pass

    def _note(self, msg: str) -> None:
        """Keep ``msg`` in :attr:`errors` (bounded: the first :data:`MAX_ERRORS` distinct ones, each with its
        count in :attr:`error_counts`) and log it the first time only."""
        n = self.error_counts.get(msg)
        if n is not None:
            self.error_counts[msg] = n + 1
            return
        if len(self.errors) >= MAX_ERRORS:
            self.errors_dropped += 1
            return
        self.error_counts[msg] = 1
        self.errors.append(msg)
        self.log.error("%s: safe state (logged once; repeats are counted)", msg)

    def _look(self) -> bool:
        for level_check in self.level_checks:
            try:
                level_check()
            except Exception as exc:  # noqa: BLE001 - one broken input must not skip the liveness check
                self._failed(exc)
        now = self.clock.now()
        if not self.tripped and now - self.last_alive_s() > self.timeout_s:
            self.tripped = True
            cut = getattr(self.actuators, "cut_engine_now", None)
            if cut is not None:  # the engine first, without the driver's lock (the frozen loop may hold it)
                cut()
            enter_safe_state(self.actuators)
            self.silent_s = now - self.last_alive_s()
            self.tripped_at_s = self.clock.now()
            if self.on_trip is not None:
                self.on_trip(self.silent_s)
        if self.tripped:
            service = getattr(self.actuators, "service", None)
            if service is not None:
                service()
            else:
                self.actuators.tick(now)
        return self.tripped

    def step(self) -> None:
        """One turn of the watchdog thread's body: a look, and the last guard around it.  The thread
        (:meth:`start_thread`) runs it every :attr:`period_s`; a virtual loop steps the same body."""
        try:
            self.check()  # (check() catches everything itself; this is the last line of defence)
        except BaseException as exc:  # noqa: BLE001
            try:
                self._failed(exc)
            except BaseException:  # noqa: BLE001 - _failed guards itself; belt and braces
                self.tripped = True

    @property
    def period_s(self) -> float:
        """How often it looks: a twentieth of the timeout (25 ms at 0.5 s).  Once tripped, its looks are
        what advance the release's relay sequencing (enable off -> settle -> relay -> settle -> enable on)
        while the loop is gone, so a coarse period would delay the release itself (bench_safety, --mock-pins
        loop-stall:800)."""
        return max(self.timeout_s / 20, 0.005)

    def next_wait_s(self, period_s: float) -> float:
        """How long the thread may sleep before its next look: ``period_s`` once tripped (its looks service the
        release) or with level checks (each look reads an input); else until the last sign of life is
        ``timeout_s`` old (a kick meanwhile moves that on: the look then finds it and sleeps again)."""
        if self.tripped or self.level_checks:
            return period_s
        try:
            left = self.last_alive_s() + self.timeout_s - self.clock.now()
        except Exception:  # noqa: BLE001  (a clock that fails: look at the usual rate; the look itself reports it)
            return period_s
        return min(max(left, 0.0) + 0.001, self.timeout_s)  # (1 ms past it: the silence is then over the timeout)

    async def run(self, period_s: float | None = None) -> None:
        """asyncio task: ``asyncio.create_task(watchdog.run())``; cancel to stop."""
        period = period_s or self.period_s
        while True:
            self.check()
            await asyncio.sleep(period)

    def start_thread(self, period_s: float | None = None) -> threading.Thread:
        """Same job on a daemon thread: still runs if the event loop itself hangs.

        While nothing needs a look every period (not tripped, no level checks) the thread sleeps to the instant
        the loop's silence would reach the timeout (:meth:`next_wait_s`): a loop that beats keeps it asleep for
        a whole timeout at a time (2 wake-ups a second at 0.5 s instead of 40), and a trip is seen at the
        timeout itself, not up to a period after it."""
        period = period_s or self.period_s

        def loop():
            wait = period
            while not self._stop.wait(wait):
                self.step()
                wait = self.next_wait_s(period)

        self._thread = threading.Thread(target=loop, name="dyno-watchdog", daemon=True)
        self._thread.start()
        return self._thread

    def stop_thread(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
