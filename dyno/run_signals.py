"""``dyno run``'s signal handling: SIGINT/SIGTERM/SIGHUP end the run safe state first, with an abort record.

``signal.signal`` (not the loop's handler) so that a real rig's outputs are safed even while the loop is
busy; the bookkeeping then runs on the loop.  On the simulated rig's own driver the whole abort runs on the
loop at once (same simulated instant); under ``--mock-pins`` the rig's path is taken, through the twin (the
driver defers a safe state asked inside one of its own commands to that command's end, and the simulated bus
does not re-enter a physics step it is in).  Installed before the rig
is built: a signal that comes while it is (no context yet) is held and acted on once it exists.
"""

from __future__ import annotations

import signal


def install_run_signal_handlers(get_ctx, loop):
    """Install the handlers; returns ``(restore, armed)``: ``restore()`` puts the previous handlers back,
    ``armed()`` is called once the context exists (a signal held until then is acted on)."""
    held: list[int] = []
    old = {}

    def on_loop(signum: int) -> None:
        name = signal.Signals(signum).name
        get_ctx().controller.abort("signal", f"{name} received: safe state, run closed")

    def handler(signum, frame) -> None:
        ctx = get_ctx()
        if ctx is None:  # still building the rig: nothing to make safe yet (nothing has moved)
            if not held:
                held.append(signum)
            return
        if ctx.signal_received is None:
            ctx.signal_received = signum
        if ctx.sim is None or ctx.pi_outputs:  # the Pi's output code (the rig, or its twin): safe at once
            from dyno.control.outputs import enter_safe_state

            enter_safe_state(ctx.controller.act, latch=True)  # at once, latched, whatever the loop is doing
        loop.call_soon_threadsafe(on_loop, signum)

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        try:
            old[sig] = signal.signal(sig, handler)
        except (ValueError, OSError):  # not the main thread
            pass

    def restore() -> None:
        for sig, h in old.items():
            signal.signal(sig, h)

    def armed() -> None:
        if held:
            handler(held[0], None)

    return restore, armed
