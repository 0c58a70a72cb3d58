"""``dyno run``'s signal handling: SIGINT/SIGTERM/SIGHUP end the run safe state first, with an abort record.

``signal.signal`` (not the loop's handler) so that a real rig's outputs are safed even while the loop is
busy; the bookkeeping then runs on the loop.  On the simulated rig's own driver the whole abort runs on the
loop at once (same simulated instant); under ``--mock-pins`` the rig's path is taken, through the twin (the
driver defers a safe state asked inside one of its own commands to that command's end, and the simulated bus
does not re-enter a physics step it is in).  Installed before the rig
is built: a signal that comes while it is (no context yet) is held and acted on once it exists.
The live UI session (:mod:`dyno.ui.session`) installs the same handlers, with its own last words and hooks.
"""

from __future__ import annotations

import signal


class RunSignals:
    """The run's signal handlers, installed before its context exists (:meth:`install`); :meth:`armed` hands
    them the context once it is built (a signal held until then is acted on), :meth:`restore` puts the
    previous handlers back."""

    def __init__(self, loop, *, closed: str = "run closed", on_signal=None, after_abort=None,
                 record: bool = True) -> None:
        self.loop = loop
        self.closed = closed  # the abort record's last words ("session closed" in the UI)
        self.on_signal = on_signal  # f(signum) in the handler, first (the UI: a hang-up detaches the terminal)
        self.after_abort = after_abort  # f(signum) on the loop after the abort (the UI: the app quits)
        self.record = record  # ctx.signal_received: the run's exit code and safety record (dyno run)
        self.ctx = None
        self._held: list[int] = []
        self._old: dict = {}

    def _on_loop(self, signum: int) -> None:
        name = signal.Signals(signum).name
        self.ctx.controller.abort("signal", f"{name} received: safe state, {self.closed}")
        if self.after_abort is not None:
            self.after_abort(signum)

    def _handler(self, signum, frame) -> None:
        if self.on_signal is not None:
            self.on_signal(signum)
        ctx = self.ctx
        if ctx is None:  # still building the rig: nothing to make safe yet (nothing has moved)
            if not self._held:
                self._held.append(signum)
            return
        if self.record and ctx.signal_received is None:
            ctx.signal_received = signum
        if ctx.sim is None or ctx.pi_outputs:  # the Pi's output code (the rig, or its twin): safe at once
            from dyno.control.outputs import enter_safe_state

            enter_safe_state(ctx.controller.act, latch=True)  # at once, latched, whatever the loop is doing
        self.loop.call_soon_threadsafe(self._on_loop, signum)

    def install(self) -> RunSignals:
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            try:
                self._old[sig] = signal.signal(sig, self._handler)
            except (ValueError, OSError):  # not the main thread
                pass
        return self

    def restore(self) -> None:
        for sig, h in self._old.items():
            signal.signal(sig, h)
        self._old = {}

    def armed(self, ctx) -> None:
        self.ctx = ctx
        if self._held:
            self._handler(self._held[0], None)
