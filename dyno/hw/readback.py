"""What :class:`dyno.hw.outputs.GpioActuators` reports of its outputs: read back from the pins, not wished.

A mixin of the driver: these read its devices and release state (with its lock held).
"""

from __future__ import annotations


class ReadbackMixin:
    def pin_states(self) -> dict[str, float]:
        """Electrical state of every output pin (1 = driven high), for doctor and tests."""
        devs = {"brake_enable": self._enable, "brake_direction": self._direction, "engine_kill": self._kill,
                "arduino_reset": self._reset, "throttle_servo": self._throttle}
        return {name: (float(d.pin.state) if d.pin is not None else float("nan")) for name, d in devs.items()}

    def output_states(self) -> dict:
        """The outputs by name, read back from the pins, and ``safe`` (:meth:`_output_states`)."""
        with self._held():
            return self._output_states()

    def _output_states(self) -> dict:
        """The outputs by name (as ``SimActuators.output_states``), the release's confirmation, the wiring
        faults the driver found (``faults``), and ``safe``.

        After ``close()`` the pins are released: every output is at its de-energised value, which the wiring
        makes the safe one (hardware/README.md) — but the brake is only known off if its release completed.
        """
        basis = {"released": self.release_confirmed, "release_basis": self.release_basis}
        if self.release_interrupted:
            basis["release_interrupted"] = self.release_interrupted
        if self.faults:
            basis["faults"] = [dict(f) for f in self.faults]
        if self.closed:
            return {"throttle": "idle", "engine_kill": "killed", "brake_actuator": "stopped",
                    "brake_estimate": round(self.brake_position, 3), "pins": "released", **basis,
                    "safe": self.release_confirmed}
        th = self.config.throttle
        pulse_us = float(self._throttle.value) * th.frame_us
        idle = abs(pulse_us - th.idle_pulse_us) < 1.0
        killed = bool(self._kill.value)
        if not self._enable.value:
            brake = "stopped"
        else:
            brake = "applying" if self._direction.value else "releasing"
        span = th.full_pulse_us - th.idle_pulse_us
        return {"throttle": "idle" if idle else f"{(pulse_us - th.idle_pulse_us) / span:.2f}",
                "engine_kill": "killed" if killed else "run", "brake_actuator": brake,
                "brake_estimate": round(self.brake_position, 3), **basis,
                "safe": idle and killed and brake == "stopped" and self.release_confirmed}
