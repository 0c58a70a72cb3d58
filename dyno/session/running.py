"""A built run's test on the running loop (:class:`RunningTest`): what :func:`dyno.session.root.run_test_async`
and the UI's session do between :func:`dyno.session.root.build` and the run's close.  Split from the root along
that seam: the root builds the run's parts once; this runs them, starts and stops them."""

from __future__ import annotations

import asyncio
from dyno.session.safety import start_watchdog
from dyno.session.signals import RunSignals


class RunningTest:
    """A built run's test on the running loop: the one way ``dyno run`` (:func:`run_test_async`) and ``dyno ui``
    (:class:`dyno.ui.session.LiveSession`) run it, between :func:`build` and the run's close.

    Constructing it on the real rig with ``exit_guard`` (a long-lived face: the UI) installs a
    :class:`~dyno.hw.safety.SafetyGuard` (the safe state on SIGTERM and at the interpreter's exit) until
    :meth:`release_guard`.  :meth:`start`: the drills armed from the first frame, the watchdog beside the loop, the
    poller's task; :meth:`run_controller` (headless) or :meth:`start_controller` (a task: the UI) runs the test;
    :meth:`rearm` hands the rig to the next run's controller (:mod:`dyno.session.next_run`); :meth:`stop` ends the
    polls, the drills and the watchdog.
    """

    def __init__(self, ctx, loop, *, exit_guard: bool = False) -> None:
        # ctx: the built run (dyno.session.root.RunContext; the root imports this module, not the reverse)
        self.ctx = ctx
        self.loop = loop
        self.poll_task: asyncio.Task | None = None
        self._stop_watchdog = None
        self.guard = None
        if exit_guard and ctx.hw is not None:  # pragma: no cover - needs the rig
            import signal

            from dyno.hw.safety import SafetyGuard

            self.guard = SafetyGuard(ctx.controller.act, signals=(signal.SIGTERM,))
            self.guard.__enter__()

    @property
    def started(self) -> bool:
        return self.poll_task is not None

    def start(self, *, signals: RunSignals | None = None, before_first_poll=None) -> None:
        """The safety first (the watchdog started, the drills checked and armed from the first frame), then
        ``signals`` (the run's handlers, held while it was built) handed the context, then the poller's task
        (``before_first_poll()`` in it, in the same loop step as the first poll: the UI's rig time zero)."""
        ctx = self.ctx
        self._stop_watchdog = start_watchdog(ctx, self.loop)
        if ctx.drills is not None:
            ctx.drills.arm_from_first_frame(ctx)
        if signals is not None:
            signals.armed(ctx)
        self.poll_task = asyncio.create_task(self._polls(before_first_poll), name="poller")

    async def _polls(self, before_first_poll) -> None:
        if before_first_poll is not None:
            before_first_poll()
        await self.ctx.poller.run()  # (its first tick reads the bus before it first awaits)

    async def run_controller(self, max_s: float | None):
        """Run the controller to its end in this task (at most ``max_s``: then aborted); returns its state."""
        ctrl = self.ctx.controller
        try:
            return await asyncio.wait_for(ctrl.run(), max_s)
        except TimeoutError:
            ctrl.abort("timeout", f"run exceeded {max_s:.0f} s")
            return ctrl.state

    def start_controller(self) -> asyncio.Task:
        """The context's controller run as a task (the UI's: its loop is the app's)."""
        return asyncio.create_task(self.ctx.controller.run(), name="controller")

    def rearm(self, log, *, listeners=()):
        """The next run's controller over the same rig and watchdog (:func:`dyno.session.next_run.start_next_controller`);
        returns it, not started."""
        from dyno.session.next_run import start_next_controller

        ctrl, self._stop_watchdog = start_next_controller(self.ctx, log, loop=self.loop,
                                                          stop_watchdog=self._stop_watchdog, listeners=listeners)
        return ctrl

    async def stop(self, *, cancel=()) -> None:
        """The drills cancelled, the polls stopped and the ``cancel`` tasks cancelled, all awaited, the watchdog
        stopped."""
        ctx = self.ctx
        if ctx.drills is not None:
            ctx.drills.cancel()
        for t in reversed(list(cancel)):
            t.cancel()
        if self.poll_task is not None:
            ctx.poller.stop()
        await asyncio.gather(*cancel, *([self.poll_task] if self.poll_task is not None else []),
                             return_exceptions=True)
        if self._stop_watchdog is not None:
            self._stop_watchdog()
            self._stop_watchdog = None

    def release_guard(self) -> None:
        if self.guard is not None:  # pragma: no cover - needs the rig
            self.guard.__exit__(None, None, None)
            self.guard = None
