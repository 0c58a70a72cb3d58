"""The E-stop chain's monitor input (``pins.estop_input`` in rig.toml).

The hard-wired chain kills the ignition without the Pi (hardware/README.md); this
input tells the software so it can put the *other* outputs in their safe state
(brake release, throttle idle) and record the stop.  The contact is normally
closed to ground with the Pi's pull-up on: closed reads low ("pressed" for
gpiozero), open reads high.  Open means STOP, so a pressed button, a cut wire or a
pulled connector all stop the rig.

gpiozero calls ``when_released`` from its edge thread (lgpio's alert callback on a
Pi: well under a millisecond after the edge), so the safe state does not wait for
the event loop; :meth:`poll` is the level check the watchdog thread repeats, in
case an edge is ever missed.
"""

from __future__ import annotations

from gpiozero import Button


class EstopInput:
    """Watch the E-stop chain; call ``on_open(detail)`` once per opening, after ``safe_state()``.

    An opening ends when the chain is seen closed again (its edge, or a level check): the next opening —
    a second E-stop after a re-arm — is a new stop with its own record.  ``openings`` counts them.
    """

    def __init__(self, bcm: int, actuators, *, pin_factory=None, bounce_time_s: float | None = None) -> None:
        self.actuators = actuators
        self.on_open = []  # callables(detail); e.g. the app's abort, marshalled onto its loop
        self.tripped = False  # the chain is open now (an opening in progress)
        self.openings = 0
        self.bcm = bcm
        # pull_up: the NC contact pulls the pin to ground while the chain is intact
        self._button = Button(bcm, pull_up=True, bounce_time=bounce_time_s, pin_factory=pin_factory)
        self._button.when_released = self._opened
        self._button.when_pressed = self._closed
        if not self._button.is_pressed:  # open at start-up: stopped from the first instant
            self._opened()

    @property
    def is_open(self) -> bool:
        return not self._button.is_pressed

    def _opened(self, *_args) -> None:
        self.actuators.safe_state(latch=True)  # first, before anything else
        if self.tripped:
            return
        self.tripped = True
        self.openings += 1
        detail = f"E-stop chain open (GPIO{self.bcm})" + (f", opening {self.openings}" if self.openings > 1 else "")
        for fn in list(self.on_open):
            try:
                fn(detail)
            except Exception:  # a listener's failure must not undo the safe state above
                pass

    def _closed(self, *_args) -> None:
        self.tripped = False  # the outputs stay latched: only the operator's re-arm clears them

    def poll(self) -> bool:
        """Level check (the watchdog thread): True if the chain is open (safe state commanded, again: a
        release already running carries on, ``GpioActuators.safe_state``)."""
        if self.is_open:
            self._opened()
            return True
        if self.tripped:
            self._closed()
        return False

    def close(self) -> None:
        self._button.close()
