"""What :class:`dyno.hw.outputs.GpioActuators` reports of its outputs: read back from the pins, not wished,
and its state (the latch, the release, the ignition hold, a standing fault).

A mixin of the driver: these read its devices and release state (with its lock held).
"""

from __future__ import annotations

from dyno.control.outputs import STOP


class ReadbackMixin:
    def rearm_refusal(self) -> str | None:
        """Why the latch may not be cleared now (None: it may): the release running, or a wiring fault."""
        if self._safe_release and self.release_basis is None:
            return "the brake's release stroke is still running"
        return self.fault_refusal()

    def fault_refusal(self) -> str | None:
        """A standing wiring fault (the end switch's): no GO, no re-arm, until ``dyno doctor --toggle`` passes."""
        es = self._end_switch
        if es is not None and es.fault:
            return (f"the end-of-travel switch {es.fault.partition(':')[0]}: fix it, then `dyno doctor --toggle` "
                    "must pass before the rig is armed again")
        return None

    @property
    def ignition_held(self) -> bool:
        """The kill chain must stay open: the brake's position is unknown (start-up, a gap) and its release
        has not yet run the full stroke (the controller waits on this before it enables the ignition)."""
        with self._held():
            if not self.closed:
                self._advance(self.clock.now())
            return self._blind

    def end_switch_closed(self) -> bool | None:
        """The end switch's raw reading (None: none declared) — for ``dyno doctor``, whatever its verdict."""
        return None if self._end_switch is None else self._end_switch.closed()

    @property
    def latched(self) -> bool:
        return self._latched

    @property
    def released(self) -> bool:
        """Brake at its release stop with the actuator de-energised."""
        return self._moving == STOP and self._target == STOP and self._position <= 0.0 \
            and (self.closed or not self._enable.value)

    @property
    def release_confirmed(self) -> bool:
        """The last safe state's release is known complete (``release_basis``) and the actuator is off."""
        return self.released and self.release_basis is not None

    @property
    def brake_position(self) -> float:
        """Estimated travel, 0 released .. 1 full apply."""
        return min(1.0, max(0.0, self._position))

    @property
    def throttle_fraction(self) -> float:
        return self._throttle_fraction

    @property
    def engine_killed(self) -> bool:
        return self._killed  # kept in Python: readable after close()

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
