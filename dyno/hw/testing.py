"""Test support for the hardware layer: a gpiozero mock factory that records pin history.

Importable by any test suite (the simulated rig's too) so "direction never
changes with the enable on" is checked the same way everywhere.
"""

from __future__ import annotations

from gpiozero.pins.mock import MockFactory, MockPWMPin


class RecordingPin(MockPWMPin):
    """A mock PWM pin that appends (time, bcm, state) to the factory's shared log.

    One shared log keeps the true order of changes across pins, which the
    "direction never changes with the enable on" check needs.
    """

    def _change_state(self, value):
        changed = super()._change_state(value)
        if changed:
            f = self.factory
            f.log.append((f.clock.now() if f.clock else 0.0, self.info.name, float(value)))
        return changed


class EstopChainPin(RecordingPin):
    """The E-stop input wired as on the rig: a normally closed contact to ground.

    The chain, not the pull-up, decides the level while it is closed (gpiozero's mock
    pin would let ``pull_up`` drive it high); :meth:`open_chain` is the button pressed
    or the wire cut, :meth:`close_chain` the chain restored.
    """

    chain_closed = True

    def _set_pull(self, value):
        super()._set_pull(value)
        if self.chain_closed:
            self.drive_low()

    def open_chain(self) -> None:
        self.chain_closed = False
        self.drive_high()  # the pull-up wins

    def close_chain(self) -> None:
        self.chain_closed = True
        self.drive_low()


class RecordingFactory(MockFactory):
    def __init__(self, clock=None):
        super().__init__(pin_class=RecordingPin)
        self.clock = clock
        self.log: list[tuple[float, str, float]] = []


def gpio(n: int) -> str:
    return f"GPIO{n}"


def assert_direction_never_switched_with_enable_on(log, rig):
    en, dr = gpio(rig.pins.brake_enable), gpio(rig.pins.brake_direction)
    enable = 0.0
    for t, name, value in log:
        if name == en:
            enable = value
        elif name == dr:
            assert enable == 0.0, f"direction relay changed with enable on at t={t}"


def assert_settled_before_enable(log, rig):
    """Enable goes on only relay_settle_s after the last relay change, and vice versa."""
    en, dr = gpio(rig.pins.brake_enable), gpio(rig.pins.brake_direction)
    settle = rig.actuator.relay_settle_s
    last_relay = last_enable_off = float("-inf")
    for t, name, value in log:
        if name == dr:
            assert t - last_enable_off >= settle - 1e-9, "relay switched before the enable had settled off"
            last_relay = t
        elif name == en:
            if value:
                assert t - last_relay >= settle - 1e-9, "enable on before the relay had settled"
            else:
                last_enable_off = t
