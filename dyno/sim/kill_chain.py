"""The ignition's kill chain as wired (hardware/README.md): who may cut the engine, and who did.

The kill relay's coil is fed through the E-stop's NC contact and two switches in series, the Pi's
(GPIO24, ``engine_enabled``) and the Nano's run-enable (D7, ``nano_enable``, issue 37): the engine runs
only while all three allow it, and K3 (``brake_hold_relay``) sits on the same chain, so whichever drops
first also releases the brake by wiring.  The first input to open the chain is recorded, in true time,
as the physics sees it: ``ignition_log`` holds ``(t_s, on, by)`` at every change, ``by`` one of
``"pi"``, ``"nano"``, ``"estop"``, and ``ignition_cut_mm`` the actuator's true position at each opening
(the start of K3's release).

Three wiring faults (the drills of :mod:`dyno.session.drills_kill`, issue 49) defeat a path: ``pi_switch_welded``
(the Pi's switch in the chain conducts whatever GPIO24 says: Q1 shorted, or an ``energise_to_kill`` rig's own
kill relay welded), ``run_enable_shorted`` (Q2 or D7's wire shorted: the chain ignores the Nano) and
``kill_lead_open`` (the magneto's kill lead or its ground return open: K1's contact grounds nothing, so the
engine fires whatever the chain does; the chain itself, and K3 on it, still switch).
"""

from __future__ import annotations


class KillChain:
    """The chain's inputs, its wiring faults and its record (owned by :class:`dyno.sim.physics.RigModel`, which
    notes it every physics cell and stops the engine while the magneto does not fire)."""

    def __init__(self) -> None:
        self.engine_enabled = True      # the Pi's switch (GPIO24)
        self.nano_enable = True         # the Nano's run-enable (a rig or firmware without one: always closed)
        self.estop_open = False         # the E-stop chain's NC contact opened (the wiring twin sets it)
        self.pi_switch_welded = False
        self.run_enable_shorted = False
        self.kill_lead_open = False
        self.log: list[tuple[float, bool, str | None]] = []  # (t_s, on, by) at every change
        self.cut_mm: dict[float, float] = {}  # the actuator's true position at each opening
        self._was_on: bool | None = None

    @property
    def ignition_on(self) -> bool:
        """The kill relay is energised: Pi, Nano and E-stop all allow the engine to run."""
        return ((bool(self.engine_enabled) or self.pi_switch_welded) and (bool(self.nano_enable) or self.run_enable_shorted)
                and not self.estop_open)

    @property
    def magneto_fires(self) -> bool:
        """The ignition sparks: the chain holds K1 off the kill lead, or the kill lead is open."""
        return self.ignition_on or self.kill_lead_open

    def _who_opened(self) -> str:
        if self.estop_open:
            return "estop"
        if not self.nano_enable and not self.run_enable_shorted and (self.engine_enabled or self.pi_switch_welded):
            return "nano"
        return "pi"

    def note(self, t_s: float, actuator_mm: float) -> bool:
        """Record a change of the chain at ``t_s`` (the actuator then at ``actuator_mm``); returns ``ignition_on``."""
        on = self.ignition_on
        if on != self._was_on:
            self.log.append((t_s, on, None if on else self._who_opened()))
            if not on:
                self.cut_mm[t_s] = float(actuator_mm)
            self._was_on = on
        return on

    @property
    def enabled_at_s(self) -> float | None:
        """When the chain first closed (true time); None if it never did."""
        return next((t_s for t_s, on, _ in self.log if on), None)

    def engine_cut(self, after_s: float = 0.0) -> tuple[float, str] | None:
        """(true time, by whom) of the first opening of the chain at or after ``after_s``, while the engine
        ran or had been enabled; None if the chain stayed closed (or was never closed)."""
        was_on = False
        for t_s, on, by in self.log:
            if not on and was_on and t_s >= after_s:
                return t_s, by
            was_on = was_on or on
        return None
