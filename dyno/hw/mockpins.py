"""``--mock-pins``: the simulated rig driven through the real-rig output code.

The controller talks to :class:`dyno.hw.outputs.GpioActuators` (the code that runs
on the Pi) built on gpiozero's ``MockFactory``; every pin change is mirrored onto
the simulated physics' inputs, the way the wiring carries it to the real actuator,
relay and servo:

* ``brake_enable`` off → actuator stopped; on → moving in the direction the
  ``brake_direction`` relay selects (energised = apply, rest = release);
* ``engine_kill`` → ignition enabled or killed, as ``kill_relay`` wires it;
* ``throttle_servo`` PWM duty → pulse width → throttle fraction.

So the relay settle, the release stroke's timing and the latching are those of
the real output code, under every drill.  The pins run on the loop's clock (virtual
time in simulations), like the rest of the host.
"""

from __future__ import annotations

from dyno.control.outputs import APPLY, RELEASE, STOP
from dyno.hw.testing import RecordingFactory, RecordingPin


class _BridgePin(RecordingPin):
    def _change_state(self, value):
        changed = super()._change_state(value)
        if changed and self.factory.bridge is not None:
            self.factory.bridge(self.info.name, float(value))
        return changed


class SimPinFactory(RecordingFactory):
    """A MockFactory whose output pins drive a simulated rig's inputs (:class:`SimActuators`)."""

    def __init__(self, rig_cfg, sim_actuators, clock=None) -> None:
        super().__init__(clock)
        self.pin_class = _BridgePin
        self.rig_cfg = rig_cfg
        # the copper, not the simulated driver: the real-rig output code in front is the driver here
        self.sim = getattr(sim_actuators, "wiring", sim_actuators)
        p = rig_cfg.pins
        self._role = {f"GPIO{p.brake_enable}": "enable", f"GPIO{p.brake_direction}": "direction",
                      f"GPIO{p.engine_kill}": "kill", f"GPIO{p.throttle_servo}": "throttle"}
        self._level = {"enable": 0.0, "direction": 0.0}
        self.bridge = None  # armed once every output exists (construction drives them one by one)

    def arm(self) -> None:
        for name, role in self._role.items():
            self.bridge = self._on_change
            self._on_change(name, float(self.pin(name).state))

    def _on_change(self, name: str, value: float) -> None:
        role = self._role.get(name)
        if role in ("enable", "direction"):
            self._level[role] = value
            if role == "direction":  # the coil: the sim's relay starts its transfer now
                self.sim.relay(APPLY if value >= 0.5 else RELEASE)
            if self._level["enable"] < 0.5:
                self.sim.brake(STOP)
            else:
                self.sim.brake(APPLY if self._level["direction"] >= 0.5 else RELEASE)
        elif role == "kill":
            high_kills = self.rig_cfg.kill_relay == "energise_to_kill"
            self.sim.engine_kill((value >= 0.5) == high_kills)
        elif role == "throttle":
            th = self.rig_cfg.throttle
            pulse_us = value * th.frame_us
            self.sim.throttle((pulse_us - th.idle_pulse_us) / (th.full_pulse_us - th.idle_pulse_us))


def mock_pin_actuators(rig_cfg, sim_actuators, clock):
    """GpioActuators on a :class:`SimPinFactory` wired to ``sim_actuators``; returns (actuators, factory)."""
    from dyno.hw.outputs import GpioActuators

    factory = SimPinFactory(rig_cfg, sim_actuators, clock)
    act = GpioActuators(rig_cfg, pin_factory=factory, clock=clock)
    factory.arm()
    return act, factory
