"""What the test controller drives: the rig's outputs, as an interface.

Implementations: :class:`dyno.sim.rig.SimActuators` (the simulated rig) and
:mod:`dyno.hw.outputs` (gpiozero on the Raspberry Pi).  The controller only
says *what* (gpiozero's devices-over-pin-factories split); implementations say
*how*.

Safe state = throttle idle, engine killed, brake released.  Releasing means
retracting the actuator for its full stroke and then de-energising it; an
implementation must make ``safe_state()`` take effect at once (no blocking)
and must never reverse the direction relay with the enable on.
"""

from __future__ import annotations

import asyncio
from typing import Protocol, runtime_checkable

APPLY = +1  # extend the actuator: more brake
RELEASE = -1  # retract: less brake
STOP = 0


@runtime_checkable
class Actuators(Protocol):
    #: seconds for a full stroke (release from full apply)
    brake_full_stroke_s: float

    def brake(self, direction: int) -> None:
        """Start moving the brake actuator (APPLY/RELEASE) or stop it (STOP)."""

    def throttle(self, fraction: float) -> None:
        """Throttle servo, 0 = idle .. 1 = full."""

    def engine_kill(self, killed: bool) -> None:
        """True opens the ignition (kill relay); False lets the engine run."""

    def safe_state(self, latch: bool = False) -> None:
        """Throttle idle, engine killed, brake released; immediately.

        ``latch``: until ``clear_latch()`` refuse every command but the release (a trip's safe state).
        """

    def tick(self, now_s: float) -> None:
        """Give time-based behaviour (end of a release stroke) a chance to act."""

    # Optional: ``ignition_held`` (bool), the kill chain must stay open: the brake's position is unknown
    # (start-up, a gap in the driver's knowledge) until a release has run its full stroke; meanwhile
    # ``engine_kill(False)`` is refused (:func:`ignition_hold_ended`).


def enter_safe_state(actuators, latch: bool = True) -> None:
    """``actuators.safe_state(latch=...)``; for an implementation without latching, its plain safe state."""
    try:
        actuators.safe_state(latch=latch)
    except TypeError:
        actuators.safe_state()


class DeadlineService:
    """Services a driver's timed sequence (relay settle, enable, end of stroke) at the driver's own deadlines.

    The engine's beats tick the outputs every ~15 ms; a driver that sequences its relay in two settles
    (:class:`dyno.hw.outputs.GpioActuators`) would start a release up to two beats late.  One loop timer at
    the driver's next deadline (``next_event_in_s``, on its clock; ``time_scale`` host s per driver s) starts
    it a settle after the latch.  Drivers without deadlines (the simulated rig's) are left to the beats.
    """

    def __init__(self) -> None:
        self._timer: asyncio.TimerHandle | None = None

    def start(self, actuators, time_scale: float = 1.0) -> None:
        self.cancel()
        due = getattr(actuators, "next_event_in_s", None)
        if due is None:
            return
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # no loop (a unit test, the shutdown path): the beats and finish_release serve
            return
        wait_s = due()
        if wait_s is None:
            return

        def fire() -> None:
            self._timer = None
            actuators.service()
            self.start(actuators, time_scale)

        # a hair past the deadline: the driver compares `now < deadline`
        self._timer = loop.call_later(wait_s * time_scale + 1e-4, fire)

    def cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None


async def ignition_hold_ended(engine) -> bool:
    """Wait (the engine's rig seconds, outputs serviced) while ``engine.act`` holds the kill chain open: at a
    run's start the brake's position is not known until its release has run the full stroke, and with K3 on
    the chain, closing it would end the wired release (docs/safety.md, "Start-up").  Logs the hold; False
    (the engine aborted, the ignition never enabled) if it outlasts two strokes."""
    act = engine.act

    def held() -> bool:
        return bool(getattr(act, "ignition_held", False))

    if not held():
        return True
    t0 = engine.rig_now()
    limit_s = 2.0 * float(getattr(act, "brake_full_stroke_s", 8.0)) + 1.0
    engine._log("ignition_hold", reason="the brake's position is unknown: its release runs the full stroke "
                                        "before the ignition is enabled")
    while held():
        if engine.rig_now() - t0 > limit_s:
            engine.abort("release_not_confirmed", f"the brake's start-up release did not end within {limit_s:.0f} s: "
                                                  "the ignition stays off")
            return False
        await engine.rig_sleep(0.05)
    engine._log("ignition_hold_end", held_s=engine.rig_now() - t0)
    return True
