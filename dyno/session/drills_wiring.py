"""The wiring drills: faults of the rig's switches, E-stop chain, watchdog and signal path, acted through the
wiring twin (``--mock-pins``, :mod:`dyno.hw.mockpins`) so that the Pi's own code meets them.

=========================  ==========================================================================
drill                      what happens at T
=========================  ==========================================================================
endswitch-stuck-closed     the end-of-travel switch reads closed from now on (shorted to ground)
endswitch-stuck-open       it reads open from now on (wire cut, connector off)
endswitch-bounce           it wears: 30 ms of chatter at each transition, and a loose contact that
                           reads closed on 5 % of reads while open
estop-held:S               the E-stop is pressed (its chain opens) and held S seconds
estop-twice                the E-stop pressed for 0.5 s; again 1 s after the session is re-armed (``dyno ui``; in
                           ``dyno run``, which has no re-arm, the first press alone)
watchdog-error             the watchdog's look raises on every look from now on, and its own logging of the
                           first one raises too (its log file unwritable)
sigint-in-command          SIGINT delivered inside the driver's next brake-apply command (between its
                           latch check and its writes; the handler runs in the middle of that command)
=========================  ==========================================================================

The end-switch drills need ``pins.brake_released_input`` in the rig file, the E-stop drills
``pins.estop_input``; all of them ``--mock-pins`` (:func:`check_wiring_drill` says which is missing).
"""

from __future__ import annotations

import os
import signal
import sys

from dyno.errors import ConfigError

#: name -> (argument required?, allowed arguments or None, needs an engine?) as ``dyno.session.drills.DRILLS``
WIRING_DRILLS: dict[str, tuple[bool, tuple | None, bool]] = {
    "endswitch-stuck-closed": (False, None, False),
    "endswitch-stuck-open": (False, None, False),
    "endswitch-bounce": (False, None, False),
    "estop-held": (True, None, False),
    "estop-twice": (False, None, False),
    "watchdog-error": (False, None, False),
    "sigint-in-command": (False, None, True),
}
#: drills that do not trip the run by themselves (the driver finds the fault and falls back)
NO_TRIP_DRILLS = ("endswitch-stuck-closed", "endswitch-stuck-open", "endswitch-bounce")
#: how long estop-twice holds each opening, and how long after the re-arm the second one comes
ESTOP_TWICE_HOLD_S = 0.5
ESTOP_TWICE_AFTER_REARM_S = 1.0


def check_wiring_drill(d, rig_cfg, twin: bool) -> None:
    """A wiring drill that cannot happen on this run is refused (ConfigError naming ``--drill``): ``twin``
    says whether the run has the wiring twin (``--mock-pins`` on the simulated rig)."""
    if d.name not in WIRING_DRILLS:
        return
    pins = getattr(rig_cfg, "pins", None)
    missing = [] if twin else ["--mock-pins (the Pi's own output code on the simulated wiring)"]
    if d.name.startswith("endswitch") and getattr(pins, "brake_released_input", None) is None:
        missing.append("an end-of-travel switch in the rig file (pins.brake_released_input in its [pins])")
    if d.name.startswith("estop") and getattr(pins, "estop_input", None) is None:
        missing.append("an E-stop monitor input in the rig file (pins.estop_input in its [pins])")
    if missing:
        raise ConfigError("command line", "--drill", f"{d}: the wiring drills run through the wiring twin; this one "
                          f"needs {' and '.join(missing)}")


class _UnwritableLog:
    """A logger whose file cannot be written (disk full, card gone): ``error`` raises."""

    def error(self, *args, **kwargs):
        raise OSError(28, "No space left on device (drill watchdog-error: the log file)")


class WiringDrills:
    """The wiring drills' actions: a mixin of :class:`dyno.session.drills.DrillRunner` (its ctx, loop, speed, handles)."""

    def _endswitch(self, mode: str) -> None:
        self.ctx.twin.end_switch_fault(mode)

    def _endswitch_stuck_closed(self, d, rec: dict) -> None:
        self._endswitch("stuck_closed")

    def _endswitch_stuck_open(self, d, rec: dict) -> None:
        self._endswitch("stuck_open")

    def _endswitch_bounce(self, d, rec: dict) -> None:
        self._endswitch("bounce")

    def _estop_held(self, d, rec: dict) -> None:
        twin = self.ctx.twin
        twin.open_estop()
        rec["held_s"] = float(d.arg)
        self._handles.append(self.loop.call_later(float(d.arg) / self.speed, twin.close_estop))

    def _estop_twice(self, d, rec: dict) -> None:
        twin = self.ctx.twin
        twin.open_estop()
        self._handles.append(self.loop.call_later(ESTOP_TWICE_HOLD_S / self.speed, twin.close_estop))
        first = self.ctx.controller

        def after_rearm(events, now_s: float) -> None:
            ctrl = self.ctx.controller
            if ctrl is first or ctrl.state.value in ("done", "aborted"):
                return
            self.ctx.poller.listeners.remove(after_rearm)
            self._handles.append(self.loop.call_later(ESTOP_TWICE_AFTER_REARM_S / self.speed, second))

        def second() -> None:
            self.ctx.sim.bus.sync()
            rec["second_onset_s"] = self.sim_now()
            rec["second_state_at_onset"] = self.ctx.controller.state.value
            twin.open_estop()
            self._handles.append(self.loop.call_later(ESTOP_TWICE_HOLD_S / self.speed, twin.close_estop))

        self.ctx.poller.listeners.append(after_rearm)

    def _watchdog_error(self, d, rec: dict) -> None:
        wd = self.ctx.watchdog

        def broken_input() -> None:
            raise OSError(5, "Input/output error (drill watchdog-error: a level check)")

        wd.log = _UnwritableLog()
        wd.level_checks.append(broken_input)

    def _sigint_in_command(self, d, rec: dict) -> None:
        from dyno.control.outputs import APPLY

        clock = self.ctx.controller.act.clock  # the driver's clock (dyno.session.safety.LoopTimeClock)
        rec["delivered_s"] = None

        def on_now() -> None:
            caller = sys._getframe(2)  # on_now <- clock.now() <- the driver's method
            if caller.f_code.co_name != "_command" or caller.f_locals.get("direction") != APPLY:
                return
            clock.on_now = None
            rec["delivered_s"] = rec["onset_s"] = self.sim_now()  # the physical onset: the signal
            os.kill(os.getpid(), signal.SIGINT)  # its handler runs here, inside the command

        clock.on_now = on_now

    def _wiring_verdict(self, rec: dict, name: str) -> tuple[bool, str]:
        """(hazard arose, why not) for the wiring drills (``dyno.session.drills.hazard_verdicts``)."""
        if name == "sigint-in-command" and rec.get("delivered_s") is None:
            return False, "no brake-apply command came after the onset: the signal was never delivered"
        return True, ""
