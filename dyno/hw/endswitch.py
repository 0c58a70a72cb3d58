"""The brake actuator's end-of-travel switch, judged against the travel the driver has integrated.

A switch is a second opinion, not the truth.  Stuck closed, shorted to ground or chattering, it would
confirm a release that never happened; stuck open or cut, it would never confirm one.  So the driver
(:class:`dyno.hw.outputs.GpioActuators`) keeps its own estimate of the actuator's travel ``x`` (fraction
of a full stroke from the retracted end, integrated from the enable's on-time since the last time the
brake was known at its stop) and takes a closed reading only where that estimate allows it:

.. math::

    x \\le \\tau(s) = \\tau_0 + k\\,s

with :math:`s` the travel integrated since the stop, both ways (the estimate's error grows with it: the
actuator's speed moves with load and supply, ~10-15 %, and each pulse starts and stops a little late or
early), :math:`\\tau_0` = :data:`ABS_TOL`, :math:`k` = :data:`REL_TOL`.  A closed reading beyond it is a
**fault** (named, kept, re-arm refused until ``dyno doctor --toggle`` checks the switch again); so is a
release that reaches the end of its full stroke + 10 % without the switch ever closing.  After a fault the
switch is ignored and every release runs its full stroke time.

Even a plausible closing does not end a release at once: the release runs on until the estimate is
:math:`\\tau` past the stop (``x <= -tau``), so a switch that closes early within the tolerance still
leaves the actuator at its end stop, and the pads off the rotor, if the speed error is within :math:`k`.
The switch's worth is the confirmation: a safe state's release from a known position then takes the
travel it needs (about a second from a loaded brake), not the full stroke from an assumed full apply.
"""

from __future__ import annotations

#: a closed reading is plausible within this fraction of the stroke of the retracted end (0.5 mm of 40 mm,
#: 0.1 s: the switch closes in the last 0.3 mm) ...
ABS_TOL = 0.0125
#: ... plus this share of the travel integrated since the last zero (the dead reckoning's drift)
REL_TOL = 0.20


def tolerance(travel: float) -> float:
    """:math:`\\tau_0 + k\\,s` (fractions of the stroke)."""
    return ABS_TOL + REL_TOL * max(0.0, travel)


class EndSwitch:
    """One declared switch (a gpiozero ``DigitalInputDevice``, pull-up on, closed = released) and its verdict.

    ``fault``: why the switch is not trusted (None: it is); ``faults``: the driver's list the fault is
    appended to (``{"channel": "end_switch", "detail", "t_s"}``).
    """

    def __init__(self, device, faults: list) -> None:
        self.device = device
        self.fault: str | None = None
        self._faults = faults
        self.closed_seen = False  # a plausible closed reading during the current release

    @property
    def trusted(self) -> bool:
        return self.fault is None

    def closed(self) -> bool:
        """The raw reading (closed to ground = released)."""
        return bool(self.device.value)

    def set_fault(self, t_s: float, detail: str) -> None:
        if self.fault is not None:
            return
        self.fault = detail
        self._faults.append({"channel": "end_switch", "detail": detail, "t_s": t_s,
                             "action": "switch ignored: every release runs its full stroke time; re-arm refused "
                                       "until `dyno doctor --toggle` passes"})
        import logging

        logging.getLogger("dyno.outputs").error("dyno: rig fault: end-of-travel switch %s (the switch is ignored: "
                                                "full-stroke releases)", detail)

    def inherit(self, fault: dict) -> None:
        """A fault an earlier session found and nobody has cleared (:mod:`dyno.hw.rig_faults`)."""
        self.fault = str(fault.get("detail", "a fault recorded earlier"))
        self._faults.append({**fault, "inherited": True})

    def judge(self, t_s: float, tracked: float | None, travel: float, stroke_s: float, doing: str) -> bool:
        """Read the switch once; True for a plausible closed reading.  A closed reading the travel rules out
        sets the fault (and returns False).  ``tracked``: the estimate from the last known stop (the driver
        does not judge while the position is unknown)."""
        if self.fault is not None or not self.closed():
            return False
        if tracked <= tolerance(travel):
            return True
        self.set_fault(t_s, f"closed {doing} at an estimated {tracked * stroke_s:.2f} s of travel "
                            f"({100 * tracked:.1f} % of the stroke) from the retracted end, beyond the "
                            f"{tolerance(travel) * stroke_s:.2f} s the estimate allows: stuck closed, shorted "
                            "to ground or a loose contact? (check the switch and its wire)")
        return False

    def never_closed(self, t_s: float, stroke_s: float) -> None:
        self.set_fault(t_s, f"did not close within the full stroke + 10 % ({1.1 * stroke_s:.1f} s of release): "
                            "stuck open, wire cut or connector off? (check the switch and its wire)")
