"""The ignition's kill chain as wired (hardware/README.md): who may cut the engine, and who did.

The kill relay's coil is fed through the E-stop's NC contact and two switches in series, the Pi's
(GPIO24, ``engine_enabled``) and the Nano's run-enable (D7, ``nano_enable``, issue 37): the engine runs
only while all three allow it, and K3 (``brake_hold_relay``) sits on the same chain, so whichever drops
first also releases the brake by wiring.  The first input to open the chain is recorded, in true time,
as the physics sees it: ``ignition_log`` holds ``(t_s, on, by)`` at every change, ``by`` one of
``"pi"``, ``"nano"``, ``"estop"``, and ``ignition_cut_mm`` the actuator's true position at each opening
(the start of K3's release).
"""

from __future__ import annotations


class KillChain:
    """Mixin of :class:`dyno.sim.physics.RigModel`: the chain's inputs and its record."""

    nano_enable: bool = True     # the Nano's run-enable (a rig or firmware without one: always closed)
    estop_open: bool = False     # the E-stop chain's NC contact opened (the wiring twin sets it)
    _ignition_was_on: bool | None = None

    @property
    def ignition_on(self) -> bool:
        """The kill relay is energised: Pi, Nano and E-stop all allow the engine to run."""
        return bool(self.engine_enabled) and bool(self.nano_enable) and not self.estop_open

    def _who_opened(self) -> str:
        if self.estop_open:
            return "estop"
        if not self.nano_enable and self.engine_enabled:
            return "nano"
        return "pi"

    def note_ignition(self, t_s: float) -> bool:
        """Record a change of the chain at ``t_s`` (called on every physics cell); returns ``ignition_on``."""
        on = self.ignition_on
        if on != self._ignition_was_on:
            log = self.__dict__.setdefault("ignition_log", [])
            log.append((t_s, on, None if on else self._who_opened()))
            if not on:
                self.__dict__.setdefault("ignition_cut_mm", {})[t_s] = float(self.actuator_mm)
            self._ignition_was_on = on
        return on

    @property
    def ignition_enabled_at_s(self) -> float | None:
        """When the chain first closed (true time); None if it never did."""
        return next((t_s for t_s, on, _ in self.__dict__.get("ignition_log", []) if on), None)

    def engine_cut(self, after_s: float = 0.0) -> tuple[float, str] | None:
        """(true time, by whom) of the first opening of the chain at or after ``after_s``, while the engine
        ran or had been enabled; None if the chain stayed closed (or was never closed)."""
        was_on = False
        for t_s, on, by in self.__dict__.get("ignition_log", []):
            if not on and was_on and t_s >= after_s:
                return t_s, by
            was_on = was_on or on
        return None
