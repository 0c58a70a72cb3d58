"""``--mock-pins``: the simulated rig driven through the real-rig code, over a twin of the rig's wiring.

The controller talks to :class:`dyno.hw.outputs.GpioActuators` (the code that runs on the Pi) built on
gpiozero's ``MockFactory``; every output pin change is carried to the simulated physics' inputs the way
the wiring carries it to the real actuator, relay and servo, and the declared inputs are driven by the
physics the way the real switches are:

* ``brake_enable`` off → actuator stopped; on → moving in the direction the ``brake_direction`` relay
  selects (energised = apply, rest = release; the relay's contact transfer time is the physics'
  ``relay_transfer_s``);
* ``engine_kill`` → ignition enabled or killed, as ``kill_relay`` wires it — and only while the E-stop
  chain is closed: the chain's NC contact carries the kill relay's coil supply (and K3's, where
  ``actuator.brake_hold_relay`` says it is fitted: the physics then drives the release by wiring);
* ``throttle_servo`` PWM duty → pulse width → throttle fraction (no pulses: the return spring idles it);
* ``pins.brake_released_input`` (declared): the end-of-travel switch, closed to ground while the true
  actuator is within :data:`END_SWITCH_CLOSES_MM` of its retracted stop — or stuck, or chattering
  (the ``endswitch-*`` drills: :meth:`SimPinFactory.end_switch_fault`);
* ``pins.estop_input`` (declared): the E-stop chain's monitor contact (:meth:`open_estop`, :meth:`close_estop`).

So the relay settle, the release stroke's timing, the latching and the end switch's plausibility are
those of the real output code, under every drill.  The pins run on the loop's clock (virtual time in
simulations), like the rest of the host.
"""

from __future__ import annotations

import numpy as np

from dyno.control.outputs import APPLY, RELEASE, STOP
from dyno.hw.testing import EstopChainPin, RecordingFactory, RecordingPin

#: the end switch's actuation point: closed while the actuator is this near its retracted stop
END_SWITCH_CLOSES_MM = 0.3
#: a worn switch's chatter: after each true transition it reads at random this long ...
BOUNCE_S = 0.03
#: ... and while open a loose contact reads closed on this share of reads
LOOSE_CLOSED_P = 0.05


class _BridgePin(RecordingPin):
    _carried = False  # the level reached the wiring once (a pin claimed at its idle level changes nothing, but
    #                   the copper behind it follows that level from then on: e.g. a kill pin claimed low)

    def _change_state(self, value):
        changed = super()._change_state(value)
        if (changed or not self._carried) and self.factory.bridge is not None:
            self._carried = True
            self.factory.bridge(self.info.name, float(value))
        return changed


class EndSwitchPin(RecordingPin):
    """The end-of-travel switch to ground (pull-up on): its level is the physics' every time it is read."""

    def _get_state(self):
        twin = getattr(self.factory, "twin_end_switch", None)
        if twin is not None and self._function == "input":
            closed = twin()
            if closed and self._state:
                self.drive_low()
            elif not closed and not self._state:
                self.drive_high()
        return super()._get_state()


class EstopTwinPin(EstopChainPin):
    """The E-stop chain's monitor contact (:class:`dyno.hw.testing.EstopChainPin`) on the twin."""


class SimPinFactory(RecordingFactory):
    """A MockFactory whose output pins drive a simulated rig's inputs (:class:`dyno.sim.rig.SimWiring`)
    and whose declared input pins read the physics."""

    def __init__(self, rig_cfg, sim_actuators, clock=None, seed: int = 0, reset=None, armed: bool = False) -> None:
        super().__init__(clock)
        self.pin_class = _BridgePin
        self.rig_cfg = rig_cfg
        # the copper, not the simulated driver: the real-rig output code in front is the driver here
        self.sim = getattr(sim_actuators, "wiring", sim_actuators)
        p = rig_cfg.pins
        self._role = {f"GPIO{p.brake_enable}": "enable", f"GPIO{p.brake_direction}": "direction",
                      f"GPIO{p.engine_kill}": "kill", f"GPIO{p.throttle_servo}": "throttle",
                      f"GPIO{p.arduino_reset}": "reset"}
        self._reset = reset  # callable: the Nano's RESET line pulled (``dyno doctor --sim``'s reset check)
        self._level = {"enable": 0.0, "direction": 0.0, "kill_run": 0.0}
        # armed once every output exists (construction drives them one by one), or from the start (``armed``:
        # a driver built later, e.g. by HardwareRig inside dyno doctor, each pin carried as it is claimed)
        self.bridge = self._on_change if armed else None
        self.chain_closed = True
        self.end_switch_mode: str | None = None  # None | "stuck_closed" | "stuck_open" | "bounce"
        self._rng = np.random.default_rng(seed + 7919)
        self._switch_true: bool | None = None
        self._switch_changed_s = -1e9
        self.twin_end_switch = None
        self.end_switch_pin = self.estop_pin = None
        if p.brake_released_input is not None:
            self.end_switch_pin = self.pin(p.brake_released_input, pin_class=EndSwitchPin)
            self.twin_end_switch = self._end_switch_closed
        if p.estop_input is not None:
            self.estop_pin = self.pin(p.estop_input, pin_class=EstopTwinPin)

    def arm(self) -> None:
        self.bridge = self._on_change
        for name, role in self._role.items():
            if role != "reset":  # (its idle level says nothing; only a pulse resets)
                self._on_change(name, float(self.pin(name).state))

    # --- outputs: the pins -> the physics' inputs ----------------------------------------------------
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
            self._level["kill_run"] = float((value >= 0.5) != high_kills)
            self._ignition()
        elif role == "reset":
            if self._reset is not None and (value >= 0.5) == self.rig_cfg.reset.active_high:
                self._reset()
        elif role == "throttle":
            th = self.rig_cfg.throttle
            pulse_us = value * th.frame_us
            if pulse_us <= 0.0:  # no pulses (the pin released): the servo goes limp, the return spring idles it
                self.sim.throttle(0.0)
                return
            self.sim.throttle((pulse_us - th.idle_pulse_us) / (th.full_pulse_us - th.idle_pulse_us))

    def _ignition(self) -> None:
        """The kill relay's coil is fed through the E-stop chain: the engine runs only if both allow it."""
        self.sim.engine_kill(not (self._level["kill_run"] >= 0.5 and self.chain_closed))

    # --- inputs: the physics -> the pins ------------------------------------------------------------
    def open_estop(self) -> None:
        """The E-stop pressed (or its wire cut): the chain drops the ignition by itself, then the Pi's
        monitor input sees the contact open."""
        self.chain_closed = False
        self.sim.model.estop_open = True  # (the physics records who opened the chain)
        self._ignition()
        if self.estop_pin is not None:
            self.estop_pin.open_chain()

    def close_estop(self) -> None:
        self.chain_closed = True
        self.sim.model.estop_open = False
        if self.estop_pin is not None:
            self.estop_pin.close_chain()
        self._ignition()  # (the Pi's kill pin decides again: after a trip it holds the ignition killed)

    def end_switch_fault(self, mode: str) -> None:
        """A drill: ``stuck_closed`` (shorted to ground), ``stuck_open`` (wire cut), ``bounce`` (worn:
        chatter at each transition and a loose contact that reads closed now and then)."""
        self.end_switch_mode = mode

    def _end_switch_closed(self) -> bool:
        wiring = self.sim
        wiring._sync()  # the physics up to now: the switch is where the actuator is
        model = wiring.model
        true = model.actuator_mm <= END_SWITCH_CLOSES_MM
        if true != self._switch_true:
            self._switch_true, self._switch_changed_s = true, model.t_s
        mode = self.end_switch_mode
        if mode == "stuck_closed":
            return True
        if mode == "stuck_open":
            return False
        if mode == "bounce":
            if model.t_s - self._switch_changed_s < BOUNCE_S:
                return bool(self._rng.random() < 0.5)
            return true or bool(self._rng.random() < LOOSE_CLOSED_P)
        return true


def mock_pin_actuators(rig_cfg, sim_actuators, clock, seed: int = 0):
    """GpioActuators on a :class:`SimPinFactory` wired to ``sim_actuators``; returns (actuators, factory)."""
    from dyno.hw.outputs import GpioActuators

    factory = SimPinFactory(rig_cfg, sim_actuators, clock, seed=seed)
    act = GpioActuators(rig_cfg, pin_factory=factory, clock=clock)
    factory.arm()
    return act, factory
