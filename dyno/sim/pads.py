"""When the simulated brake's pads left the rotor, as the physics sees it (true time).

``off_at_s``: the last time the actuator came back inside the brake's free travel (None while the pads
are on the rotor); ``startup_released_at_s``: the first time, for a brake that started applied
(``RigParams.brake_start_mm``, ``--sim-brake-start``), 0 for one that started off the rotor, None while a brake
that started applied has not yet let go.
"""

from __future__ import annotations


class PadsRecord:
    """The pads' record (module doc) for one brake: ``a0_mm`` its free travel, ``a_max_mm`` its stroke."""

    def __init__(self, a0_mm: float, a_max_mm: float) -> None:
        self.a0_mm = a0_mm
        self.a_max_mm = a_max_mm
        self.off_at_s: float | None = 0.0
        self.startup_released_at_s: float | None = 0.0

    def start(self, start_mm: float) -> float:
        """The actuator's true start position (clamped to its travel); sets the record to match."""
        a = min(max(0.0, float(start_mm)), self.a_max_mm)
        self.off_at_s = self.startup_released_at_s = 0.0 if a <= self.a0_mm else None
        return a

    def note(self, t0: float, h: float, a_before: float, a_after: float) -> None:
        """The actuator moved ``a_before`` -> ``a_after`` over the cell ``[t0, t0 + h]`` (constant speed)."""
        a0 = self.a0_mm
        if a_before > a0 >= a_after:  # the pads left the rotor in this cell
            self.off_at_s = t0 + h * (a_before - a0) / (a_before - a_after)
            if self.startup_released_at_s is None:
                self.startup_released_at_s = self.off_at_s
        elif a_after > a0 >= a_before:
            self.off_at_s = None
