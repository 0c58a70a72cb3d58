"""The simulated rig assembled: physics + emulated firmware + simulated bus + actuators.

``SimRig`` hands the host the same things the real rig does: an SMBus-like
object (firmware at 0x03, thermometer at 0x5A) and an
:class:`~dyno.control.outputs.Actuators`.  Its ``truth`` is for tests and the
``efficiency_true`` column only; nothing in the host path reads it.
"""

from __future__ import annotations

import math
from array import array
from bisect import bisect_left, bisect_right

import numpy as np

from dyno.control.outputs import RELEASE, STOP
from dyno.sim.bus import BusFaults, SimSMBus
from dyno.sim.device import EmulatedFirmware


class SimActuators:
    """The controller's outputs wired to the physics model's inputs."""

    def __init__(self, rig_model, full_stroke_s: float = 8.0, sync=None) -> None:
        self.model = rig_model
        # Bring the physics up to "now" before changing an input, so the input
        # acts from the moment it was commanded (not from the last bus poll).
        self._sync = sync or (lambda: None)
        self.brake_full_stroke_s = full_stroke_s
        self.history: list[tuple[float, str, object]] = []  # (sim t, what, value) for tests
        self._release_until_s: float | None = None

    def _record(self, what: str, value) -> None:
        self.history.append((self.model.t_s, what, value))

    def brake(self, direction: int) -> None:
        """Power the actuator in ``direction`` (STOP: enable off).

        Without a driver in front (the default sim) a reversal also moves the
        direction relay, and the physics keeps the motor unpowered until its
        contacts make (``RigParams.relay_transfer_s``): a pulse shorter than
        that after a reversal moves nothing, as on the rig.
        """
        self._sync()
        self._release_until_s = None
        direction = int(direction)
        self.model.actuator_dir = direction
        self._record("brake", direction)

    def relay(self, direction: int) -> None:
        """The direction relay's coil alone (a driver switching it with the enable off)."""
        self._sync()
        self.model.relay_dir = int(direction)
        self._record("relay", int(direction))

    def throttle(self, fraction: float) -> None:
        self._sync()
        self.model.throttle_frac = min(1.0, max(0.0, float(fraction)))
        self._record("throttle", self.model.throttle_frac)

    def engine_kill(self, killed: bool) -> None:
        self._sync()
        self.model.engine_enabled = not killed
        self._record("kill", bool(killed))

    def safe_state(self) -> None:
        self._sync()
        self.model.throttle_frac = 0.0
        self.model.engine_enabled = False
        self.model.actuator_dir = RELEASE
        self._release_until_s = self.model.t_s + self.brake_full_stroke_s
        self._record("safe_state", True)

    def tick(self, now_s: float) -> None:
        # The release timer runs on the physics' clock (the caller's clock may be
        # offset from it, e.g. a UI on the real loop driving a paced simulation).
        if self._release_until_s is not None and self.model.t_s >= self._release_until_s:
            self.model.actuator_dir = STOP
            self._release_until_s = None
            self._record("brake", STOP)

    @property
    def is_safe(self) -> bool:
        m = self.model
        return m.throttle_frac == 0.0 and not m.engine_enabled and m.actuator_dir in (RELEASE, STOP)

    @property
    def releasing(self) -> bool:
        """A release stroke is under way (the actuator retracts until its timer ends)."""
        return self._release_until_s is not None

    def output_states(self) -> dict:
        """The outputs by name (as the rig's pins would show them) and ``safe``."""
        m = self.model
        brake = {RELEASE: "releasing", STOP: "stopped"}.get(m.actuator_dir, "applying")
        return {"throttle": "idle" if m.throttle_frac == 0.0 else f"{m.throttle_frac:.2f}",
                "engine_kill": "killed" if not m.engine_enabled else "run",
                "brake_actuator": brake, "brake_position_mm": round(m.actuator_mm, 3),
                "safe": self.is_safe}


class TruthRecorder:
    """Samples the physics' true state at every poll, to average over point windows."""

    FIELDS = ("p_in", "p_out", "rp", "rs", "tq", "rotor_c", "ratio_geo", "slip")

    def __init__(self, model) -> None:
        self.model = model
        self.t = array("d")
        (self.p_in, self.p_out, self.rp, self.rs, self.tq, self.rotor_c, self.ratio_geo,
         self.slip) = (array("d") for _ in self.FIELDS)

    def __call__(self, events, now_s: float) -> None:
        tr = self.model.truth()
        self.t.append(tr.t_s)
        self.p_in.append(tr.power_in_w)
        self.p_out.append(tr.power_out_w)
        self.rp.append(tr.rpm_primary)
        self.rs.append(tr.rpm_secondary)
        self.tq.append(tr.torque_secondary_nm)
        self.rotor_c.append(tr.rotor_temp_c)
        self.ratio_geo.append(tr.ratio_geometric)
        self.slip.append(tr.belt_slip)

    def crossing_s(self, field: str, level: float, after_s: float = 0.0) -> float | None:
        """First time (linear interpolation between samples) ``field`` rises above ``level``."""
        a = getattr(self, field)
        t = self.t
        for i in range(max(1, bisect_left(t, after_s)), len(t)):
            if a[i] > level >= a[i - 1]:
                f = (level - a[i - 1]) / (a[i] - a[i - 1])
                return t[i - 1] + f * (t[i] - t[i - 1])
        if len(t) and bisect_left(t, after_s) < len(t) and a[bisect_left(t, after_s)] > level:
            return t[bisect_left(t, after_s)]
        return None

    def max_after(self, field: str, after_s: float) -> float:
        a = getattr(self, field)
        i = bisect_left(self.t, after_s)
        return max(a[i:]) if i < len(a) else math.nan

    def window(self, t0_s: float, t1_s: float) -> dict:
        i, j = bisect_left(self.t, t0_s), bisect_right(self.t, t1_s)
        if j <= i:
            return {}

        def mean(a):
            return float(np.mean(np.frombuffer(a, dtype=np.float64)[i:j]))

        p_in, p_out = mean(self.p_in), mean(self.p_out)
        return {"efficiency_true": p_out / p_in if p_in > 0 else math.nan,
                "rpm_primary_true": mean(self.rp), "rpm_secondary_true": mean(self.rs),
                "torque_secondary_true_nm": mean(self.tq), "power_in_true_w": p_in, "power_out_true_w": p_out,
                # the belt's truth for the slip-consistent inverse (dyno.model.inverse)
                "ratio_geometric_true": mean(self.ratio_geo), "belt_slip_true": mean(self.slip)}

    def point_hook(self, point: dict, t0_s: float, t1_s: float) -> None:
        point.update(self.window(t0_s, t1_s))


class SimRig:
    """Everything the host needs from a simulated rig.

    Parameters
    ----------
    now_s : the injected clock (the running loop's ``time``)
    protocol : "v2" (our firmware, default), "v1" (its previous protocol) or "v0" (the thesis sketch)
    faults : bus fault injection
    clock_offset_us : device counter at boot (near 2**32 to cross the wrap early)
    """

    def __init__(self, now_s, *, seed: int = 0, params=None, protocol: str = "v2",
                 faults: BusFaults | None = None, clock_offset_us: int = 0, clock_ppm: float = 0.0,
                 full_stroke_s: float = 8.0) -> None:
        from dyno.sim.physics import RigModel  # the physics is the slow import; only when simulating

        self.model = RigModel(params, seed=seed)
        self.firmware = EmulatedFirmware(protocol, clock_offset_us=clock_offset_us, clock_ppm=clock_ppm)
        self.bus = SimSMBus(self.model, self.firmware, now_s, faults, seed=seed)
        self.actuators = SimActuators(self.model, full_stroke_s=full_stroke_s, sync=self.bus.sync)
        self.truth = TruthRecorder(self.model)
        self.protocol = protocol

    def start_engine(self) -> None:
        """The operator pulls the starter cord."""
        self.model.start_engine()

    def audit(self, raw: bytes) -> bool:
        """True if ``raw`` is byte-for-byte a frame the device really served."""
        if self.firmware.protocol == "v0":
            return raw in self.firmware.served_v0
        return self.firmware.served.get(raw[3]) == raw
