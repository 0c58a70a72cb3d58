"""The brake actuator beside the calibration fixture, for ``dyno calibrate --sim --mock-pins``.

On the rig a calibration hangs weights on the locked brake rotor; the actuator, the ignition and the throttle are
still there and the Pi's output code still owns them (throttle idle, engine killed, the brake released from
wherever the last run left it).  This is that much physics and no more: a screw actuator at constant speed with
end stops at 0 and its travel, the pads off the rotor inside the free travel, the direction relay's contacts
taking their transfer time; the copper the wiring twin (:mod:`dyno.hw.mockpins`) drives.  The numbers are the
simulated rig's (:class:`dyno.sim.rig_params.RigParams`).
"""

from __future__ import annotations

import threading

from dyno.control.outputs import STOP


class FixtureActuatorModel:
    """The state the twin reads and the checks judge: ``actuator_mm``, ``t_s``, ``pads_off`` and the inputs."""

    def __init__(self, start_mm: float, params) -> None:
        self.v_mm_s = params.actuator_speed_mm_s
        self.travel_mm = params.actuator_travel_mm
        self.free_travel_mm = params.brake_free_travel_mm
        self.transfer_s = params.relay_transfer_s
        self.start_mm = self.actuator_mm = float(start_mm)  # (start_mm: where the fixture stood when powered)
        self.t_s = 0.0
        self.actuator_dir = STOP
        self.relay_dir = -1
        self.relay_made_s = 0.0
        self.engine_enabled = False
        self.throttle_frac = 0.0

    @property
    def pads_off(self) -> bool:
        return self.actuator_mm <= self.free_travel_mm

    def advance(self, t_s: float) -> None:
        if t_s <= self.t_s:
            return
        if self.actuator_dir and self.relay_dir == self.actuator_dir:
            run_s = t_s - max(self.t_s, self.relay_made_s)  # moving once the contacts have made
            if run_s > 0:
                a = self.actuator_mm + self.actuator_dir * self.v_mm_s * run_s
                self.actuator_mm = min(self.travel_mm, max(0.0, a))
        self.t_s = t_s


class FixtureActuatorWiring:
    """The copper between the Pi's pins and the fixture's actuator (as :class:`dyno.sim.rig.SimWiring`)."""

    def __init__(self, now_s, *, start_mm: float = 5.0, params=None) -> None:
        from dyno.sim.rig_params import RigParams

        self.now_s = now_s
        self.model = FixtureActuatorModel(start_mm, params or RigParams())
        self.history: list[tuple[float, str, object]] = []
        self._lock = threading.Lock()  # the watchdog thread and the loop both move it

    def _sync(self) -> None:
        with self._lock:
            self.model.advance(self.now_s())

    def _record(self, what: str, value) -> None:
        self.history.append((self.model.t_s, what, value))

    def brake(self, direction: int) -> None:
        self._sync()
        self.model.actuator_dir = int(direction)
        self._record("brake", int(direction))

    def relay(self, direction: int) -> None:
        self._sync()
        m = self.model
        if int(direction) != m.relay_dir:
            m.relay_dir, m.relay_made_s = int(direction), m.t_s + m.transfer_s
        self._record("relay", int(direction))

    def throttle(self, fraction: float) -> None:
        self._sync()
        self.model.throttle_frac = min(1.0, max(0.0, float(fraction)))
        self._record("throttle", self.model.throttle_frac)

    def engine_kill(self, killed: bool) -> None:
        self._sync()
        self.model.engine_enabled = not killed
        self._record("kill", bool(killed))

    def outputs(self) -> dict:
        """The physics' verdict: pads off, actuator de-energised, ignition killed, throttle idle."""
        self._sync()
        m = self.model
        return {"brake_position_mm": round(m.actuator_mm, 3), "pads_off_rotor": m.pads_off,
                "brake_actuator": "stopped" if m.actuator_dir == STOP else ("releasing" if m.actuator_dir < 0
                                                                           else "applying"),
                "engine_kill": "killed" if not m.engine_enabled else "run",
                "throttle": "idle" if m.throttle_frac == 0.0 else f"{m.throttle_frac:.2f}",
                "safe": m.pads_off and m.actuator_dir == STOP and not m.engine_enabled and m.throttle_frac == 0.0}
