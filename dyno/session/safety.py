"""The run's safety parts, wired by the composition root (:mod:`dyno.session.root`): the watchdog beside the loop,
the E-stop input's record, and under ``--mock-pins`` the Pi's own output code over the wiring twin.
"""

from __future__ import annotations


class LoopTimeClock:
    """The real-rig output code's clock on the host loop's time (virtual in simulations).

    Only the blocking helpers (``step``, ``finish_release``, ``reset_arduino``) sleep;
    on a virtual loop nothing may block, and the host never calls them there.  ``on_now`` (a drill's
    hook, :mod:`dyno.session.drills_wiring`) runs inside each reading: a signal delivered there arrives in the
    middle of whatever output command asked the time.
    """

    def __init__(self, now_s, sleep=None) -> None:
        self._now = now_s
        self._sleep = sleep  # a paced simulation on a real loop (dyno calibrate): its real-time equivalent
        self.on_now = None

    def now(self) -> float:
        if self.on_now is not None:
            self.on_now()
        return self._now()

    def sleep(self, dt_s: float) -> None:
        if self._sleep is None:
            raise RuntimeError("a blocking sleep on the loop's clock (use the async paths)")
        self._sleep(dt_s)


def twin_outputs(rig_cfg, sim, now_s, seed: int):
    """``--mock-pins``: ``GpioActuators`` (and ``EstopInput`` where ``pins.estop_input`` is declared) on the
    wiring twin (:mod:`dyno.hw.mockpins`) over ``sim``'s physics; returns (actuators, twin, estop or None)."""
    from dyno.hw.mockpins import mock_pin_actuators

    actuators, twin = mock_pin_actuators(rig_cfg, sim.actuators, LoopTimeClock(now_s), seed=seed)
    estop = None
    if rig_cfg.pins.estop_input is not None:
        from dyno.hw.estop import EstopInput

        estop = EstopInput(rig_cfg.pins.estop_input, actuators, pin_factory=twin)
    return actuators, twin, estop


def close_twin(ctx) -> None:
    """Release the twin's pins (the run's record is written): the wiring no longer carries them to the
    physics, so the pins' release (to their de-energised levels, as on the rig) moves nothing there."""
    twin = ctx.twin
    twin.bridge = twin.twin_end_switch = None
    if ctx.estop is not None:
        ctx.estop.close()
    close = getattr(ctx.controller.act, "close", None)
    if close is not None:
        close()


def make_watchdog(actuators, hw, estop, timeout_s: float, now_s):
    """The run's watchdog, not an asyncio task: it safes the rig if the loop stops beating.

    ``hw``: the real rig, whose own watchdog (built by HardwareRig over the real outputs, the E-stop's level among
    its checks) is the run's; else one over ``actuators`` (the twin's E-stop input checked on every look).  On a
    :class:`~dyno.clock.VirtualTimeLoop` it runs as a background ticker (the loop's stand-in for an OS thread: it
    runs while a callback blocks the loop), on a real loop as a daemon thread (:func:`start_watchdog`).  The
    controller's safety heartbeat feeds it and reports its trip (:func:`watchdog_beat`, given to the controller's
    constructor); the polls kick it too (:func:`kick_on_polls`).
    """
    from dyno.hw.safety import Watchdog

    wd = getattr(hw, "watchdog", None)
    if wd is not None:  # the rig's own (HardwareRig built it over the real outputs)
        return wd

    class _Clock:  # until start_watchdog() gives it the loop's clock
        now = staticmethod(now_s)

    return Watchdog(actuators, timeout_s, clock=_Clock(), level_checks=(estop.poll,) if estop is not None else ())


def watchdog_beat(wd, controller_of, timeout_s: float):
    """The controller's heartbeat hook (a ``heartbeat_hooks`` entry, given at its construction): feeds ``wd`` and
    reports its trip once, as an abort of ``controller_of()`` (the controller being built: called only on a beat)."""
    reported = []

    def beat() -> None:
        if wd.tripped and not reported:
            reported.append(True)
            controller = controller_of()
            if wd.silent_s is not None:
                controller.abort("watchdog", f"control loop silent for {wd.silent_s:.3f} s (watchdog "
                                 f"{timeout_s:.2f} s): the watchdog put the rig in its safe state", wd.tripped_at_s)
            else:  # a look that raised: safed, logged, still watching
                errs = getattr(wd, "errors", None) or ["tripped"]
                controller.abort("watchdog", f"{errs[0]}: the watchdog put the rig in its safe state")
        wd.kick()

    return beat


def kick_on_polls(poller, wd) -> None:
    """Polls are signs of life too (the controller's heartbeat stops with the test; the UI polls on)."""
    poller.listeners.append(_WatchdogKick(wd))


class _WatchdogKick:
    """The poller's listener that kicks the watchdog (a re-arm finds it by type, and replaces it)."""

    def __init__(self, wd) -> None:
        self.wd = wd

    def __call__(self, events, now_s: float) -> None:
        self.wd.kick()


def next_watchdog(ctx, loop):
    """The watchdog a re-armed session's next controller beats for (made before it, :func:`watchdog_beat`): the
    rig's own runs on; the session's own is replaced by a new one (:func:`rehook_watchdog` starts it)."""
    return make_watchdog(ctx.controller.act, ctx.hw, ctx.estop, ctx.rig_cfg.actuator.watchdog_s, loop.time)


def rehook_watchdog(ctx, wd, loop, stop_running):
    """Hand the polls' kick and ``ctx.watchdog`` to ``wd`` (:func:`next_watchdog`, the new controller built).
    The rig's own watchdog thread runs on and reports to the new controller; the session's own (no ``ctx.hw``)
    is stopped (``stop_running``) and ``wd`` started beside the new controller.  Returns its stop callable."""
    poller = ctx.poller
    poller.listeners[:] = [fn for fn in poller.listeners if not isinstance(fn, _WatchdogKick)]
    if ctx.hw is None and stop_running is not None:
        stop_running()
    ctx.watchdog = wd
    kick_on_polls(poller, wd)
    return start_watchdog(ctx, loop) if ctx.hw is None else stop_running


def start_watchdog(ctx, loop) -> object:
    """Start ``ctx.watchdog`` beside ``loop``; returns a stop() callable."""
    from dyno.clock import LoopClock, VirtualTimeLoop

    wd = ctx.watchdog
    estop = ctx.estop
    if estop is not None and not ctx.estop_hooked:
        # the E-stop chain's input: outputs already safe (its callback); record the stop with whichever
        # controller runs then (a re-armed session's new one: a second E-stop is a stop of its own)
        ctx.estop_hooked = True
        estop.on_open.append(lambda detail: loop.call_soon_threadsafe(
            lambda: ctx.controller.abort("estop", detail)))
        if estop.tripped:
            loop.call_soon(ctx.controller.abort, "estop", "E-stop chain open at start-up")
    # The loop's liveness is measured on the loop's own clock (the controller's time base):
    # host time on a real loop (the UI paces the physics on a scaled clock), virtual in simulations.
    wd.clock = LoopClock(loop)
    wd.kick()
    if isinstance(loop, VirtualTimeLoop):  # the thread's own body, stepped by the virtual loop
        entry = loop.add_ticker(wd.step, wd.period_s)
        return lambda: loop.remove_ticker(entry)
    wd.start_thread()
    return wd.stop_thread


#: the operator's line when nothing the program commands can stop the engine (the kill-path probe: kill_lead)
KILL_LEAD_WARNING = ("DANGER: the engine cannot be cut by dyno: neither the Pi's kill relay nor the Nano's run-enable "
                     "stopped it (kill lead or its ground return open). Stop the engine NOW at its own switch or fuel "
                     "shut-off; the E-stop's S1.2 contact on the kill wire may not stop it either.")


def uncuttable_warning(stream=None):
    """A controller listener (given at its construction): on its abort ``kill_path_failed`` with ``path``
    ``kill_lead``, one line on stderr at once (whatever the face: ``dyno run``, ``dyno ui``), for the person at
    the rig (issue 49)."""
    import sys

    said = []

    def listener(ctrl) -> None:
        if said or not any(a.get("path") == "kill_lead" for a in ctrl.aborts):
            return
        said.append(True)
        print(f"dyno: {KILL_LEAD_WARNING}", file=stream or sys.stderr, flush=True)

    return listener
