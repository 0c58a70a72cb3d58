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


def enter_safe_state(actuators, latch: bool = True) -> None:
    """``actuators.safe_state(latch=...)``; for an implementation without latching, its plain safe state."""
    try:
        actuators.safe_state(latch=latch)
    except TypeError:
        actuators.safe_state()
