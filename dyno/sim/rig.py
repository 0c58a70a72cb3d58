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


#: the release stroke runs this fraction of a full stroke beyond it before de-energising (as the real-rig
#: output code's END_STOP_OVERRUN_FRACTION), so a stroke that started at full apply still reaches the stop
RELEASE_MARGIN_FRACTION = 0.10
#: and this long on top, for the direction relay's transfer after a reversal (RigParams.relay_transfer_s)
RELEASE_MARGIN_S = 0.05
#: the operator keeps pulling the starter this long while the kill chain is still open (the real firmware's
#: run-enable comes on within a poll or two of the limits)
OPERATOR_PULLS_S = 2.0


class SimWiring:
    """The simulated rig's output wiring: the physics' inputs, set as the pins would set them.

    No policy here (no latch, no timers): this is the copper between a driver and the actuator.
    :class:`SimActuators` is the simulated driver in front of it; under ``--mock-pins`` the real-rig
    output code drives it through :mod:`dyno.hw.mockpins` instead.  ``history`` keeps every change
    ``(sim t, what, value)`` and ``history_mm`` the actuator's true position at that instant, so the
    run can state when the safe state reached the outputs and where the brake was then.
    """

    def __init__(self, rig_model, sync=None) -> None:
        self.model = rig_model
        # Bring the physics up to "now" before changing an input, so the input
        # acts from the moment it was commanded (not from the last bus poll).
        self._sync = sync or (lambda: None)
        self.history: list[tuple[float, str, object]] = []
        self.history_mm: list[float] = []

    def record(self, what: str, value) -> None:
        self.history.append((self.model.t_s, what, value))
        self.history_mm.append(self.model.actuator_mm)

    def brake(self, direction: int) -> None:
        """Power the actuator in ``direction`` (STOP: enable off).

        Without a driver in front (the default sim) a reversal also moves the
        direction relay, and the physics keeps the motor unpowered until its
        contacts make (``RigParams.relay_transfer_s``): a pulse shorter than
        that after a reversal moves nothing, as on the rig.
        """
        self._sync()
        direction = int(direction)
        self.model.actuator_dir = direction
        self.record("brake", direction)

    def relay(self, direction: int) -> None:
        """The direction relay's coil alone (a driver switching it with the enable off)."""
        self._sync()
        self.model.relay_dir = int(direction)
        self.record("relay", int(direction))

    def throttle(self, fraction: float) -> None:
        self._sync()
        self.model.throttle_frac = min(1.0, max(0.0, float(fraction)))
        self.record("throttle", self.model.throttle_frac)

    def engine_kill(self, killed: bool) -> None:
        self._sync()
        self.model.engine_enabled = not killed
        self.record("kill", bool(killed))


def wired_states(history, ignore_kill=()):
    """Replay :class:`SimWiring`'s ``history``: yields ``(index, t, safe)`` after each entry, ``safe`` being
    throttle idle, ignition killed and the actuator not applying (stopped or releasing).  ``ignore_kill``:
    (t0, t1) spans whose kill changes are not a safe state (the kill-path probe's 100 ms cuts, issue 49)."""
    throttle, enabled, direction = 0.0, True, 0
    for i, (t, what, value) in enumerate(history):
        if what == "kill" and any(t0 <= t <= t1 for t0, t1 in ignore_kill):
            continue
        if what == "safe_state":
            throttle, enabled, direction = 0.0, False, -1
        elif what == "throttle":
            throttle = float(value)
        elif what == "kill":
            enabled = not value
        elif what == "brake":
            direction = int(value)
        yield i, t, throttle == 0.0 and not enabled and direction <= 0


class SimActuators:
    """The controller's outputs on the simulated rig: a simulated driver over :class:`SimWiring`.

    Like the real-rig output code (:class:`dyno.hw.outputs.GpioActuators`) it **latches** the safe
    state: after ``safe_state(latch=True)`` every command but the release is refused (and recorded in
    ``refused``) until :meth:`clear_latch` — a plan's cleanup that says STOP cannot freeze the brake on
    the rotor.  The release stroke runs a full stroke plus margin on the physics' clock, then
    de-energises (:meth:`tick`).  ``is_safe`` is the physics' state, not the commands'.
    """

    def __init__(self, rig_model, full_stroke_s: float = 8.0, sync=None) -> None:
        self.model = rig_model
        self.wiring = SimWiring(rig_model, sync)
        self._sync = self.wiring._sync
        self.brake_full_stroke_s = full_stroke_s
        self._release_until_s: float | None = None
        self._latched = False
        self.refused: list[tuple[float, str, object]] = []  # (sim t, command, value) refused while latched
        # The brake's position is not known until a release has run its full stroke: until then the ignition
        # stays off (the kill chain open, K3 releasing) and no apply is taken (docs/safety.md, "start-up").
        self._blind = True

    @property
    def history(self) -> list:
        return self.wiring.history

    def _refuse(self, what: str, value, hard: bool) -> None:
        from dyno.errors import SafetyAbort

        self.refused.append((self.model.t_s, what, value))
        self.wiring.record("refused", f"{what}={value}")
        if hard:  # a command that would move the rig out of its safe state: the caller must know
            why = ("safe state latched" if self._latched else
                   "the brake's position is unknown until its release has run the full stroke")
            raise SafetyAbort(f"{what} refused: {why}")

    def brake(self, direction: int) -> None:
        """Power the actuator in ``direction`` (STOP: enable off); refused while latched, and an apply while
        the position is unknown (:attr:`ignition_held`)."""
        direction = int(direction)
        if self._latched or (self._blind and direction > 0):
            self._refuse("brake", direction, hard=direction > 0)
            return
        self._release_until_s = None
        self.wiring.brake(direction)

    def relay(self, direction: int) -> None:
        self.wiring.relay(direction)

    def throttle(self, fraction: float) -> None:
        if self._latched and float(fraction) > 0.0:
            self._refuse("throttle", float(fraction), hard=True)
        self.wiring.throttle(fraction)

    def engine_kill(self, killed: bool) -> None:
        if (self._latched or self.ignition_held) and not killed:
            self._refuse("engine_run", True, hard=True)
        self.wiring.engine_kill(killed)

    @property
    def ignition_held(self) -> bool:
        """The kill chain must stay open: the brake's position is unknown until a release stroke has run its
        full time (start-up)."""
        self.service()
        return self._blind

    def safe_state(self, latch: bool = False) -> None:
        """Throttle idle, ignition killed, release stroke started; ``latch``: refuse all else until re-armed.

        A release already under way keeps its end (a second safe state does not restart the stroke
        from the top, but never shortens it either).
        """
        self._sync()
        m = self.model
        m.throttle_frac = 0.0
        m.engine_enabled = False
        m.actuator_dir = RELEASE
        end = m.t_s + self.brake_full_stroke_s * (1.0 + RELEASE_MARGIN_FRACTION) + RELEASE_MARGIN_S
        if self._release_until_s is None or end > self._release_until_s:
            self._release_until_s = end
        self._latched = self._latched or latch
        self.wiring.record("safe_state", True)

    def clear_latch(self) -> None:
        """The explicit re-arm (between runs): commands are accepted again."""
        self._latched = False

    @property
    def latched(self) -> bool:
        return self._latched

    def tick(self, now_s: float) -> None:
        # The release timer runs on the physics' clock (the caller's clock may be
        # offset from it, e.g. a UI on the real loop driving a paced simulation).
        if self._release_until_s is not None and self.model.t_s >= self._release_until_s:
            self._release_until_s = None
            self._blind = False  # a full stroke ran: at the retracted stop, wherever it started
            self.wiring.brake(STOP)

    def service(self) -> None:
        """The watchdog's servicing call (as ``GpioActuators.service``): end a release that is due."""
        self.tick(self.model.t_s)

    @property
    def is_safe(self) -> bool:
        """The physics is in the safe state: throttle idle, ignition killed, pads off the rotor,
        actuator not applying (a release may still be de-energising)."""
        m = self.model
        return m.throttle_frac == 0.0 and not m.engine_enabled and m.actuator_dir in (RELEASE, STOP) \
            and m.pads_off

    @property
    def releasing(self) -> bool:
        """A release stroke is under way (the actuator retracts until its timer ends)."""
        return self._release_until_s is not None

    @property
    def released(self) -> bool:
        """Pads off the rotor and the actuator de-energised (the release stroke has ended)."""
        return self.model.pads_off and self.model.actuator_dir == STOP and not self.releasing

    def output_states(self) -> dict:
        """The outputs by name (as the rig's pins would show them) and ``safe``."""
        return physical_outputs(self.model)


def physical_outputs(model) -> dict:
    """The simulated rig's outputs as the physics has them, and ``safe``: throttle idle, ignition
    killed (the Pi's command, and no spark: a welded path or an open kill lead leave the engine firing),
    pads off the rotor (actuator at or inside the free travel) and the actuator de-energised."""
    m = model
    brake = {RELEASE: "releasing", STOP: "stopped"}.get(m.actuator_dir, "applying")
    return {"throttle": "idle" if m.throttle_frac == 0.0 else f"{m.throttle_frac:.2f}",
            "engine_kill": "killed" if not m.engine_enabled else "run",
            "brake_actuator": brake, "brake_position_mm": round(m.actuator_mm, 3),
            "pads_off_rotor": bool(m.pads_off),
            "engine_firing": bool(getattr(m, "magneto_fires", False)),
            "safe": m.throttle_frac == 0.0 and not m.engine_enabled and m.actuator_dir == STOP and bool(m.pads_off)
            and not getattr(m, "magneto_fires", False)}


class TruthRecorder:
    """Samples the physics' true state at every poll, to average over point windows."""

    FIELDS = ("p_in", "p_out", "rp", "rs", "tq", "rotor_c", "ratio_geo", "slip", "te", "dl", "act")

    def __init__(self, model) -> None:
        self.model = model
        self.t = array("d")
        (self.p_in, self.p_out, self.rp, self.rs, self.tq, self.rotor_c, self.ratio_geo,
         self.slip, self.te, self.dl, self.act) = (array("d") for _ in self.FIELDS)

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
        self.te.append(getattr(tr, "torque_engine_nm", math.nan))  # (a stand-in truth may not have it)
        self.dl.append(getattr(tr, "driveline_loss_nm", 0.0))
        self.act.append(getattr(tr, "actuator_mm", math.nan))  # the brake actuator's true position

    def trim_before(self, t_s: float) -> int:
        """Forget the samples older than ``t_s`` (a UI session re-arms on one rig: each run's truth is
        averaged into its points when they are taken, so only the windows still to come need samples)."""
        i = bisect_left(self.t, t_s)
        if i:
            for a in (self.t, *(getattr(self, f) for f in self.FIELDS)):
                del a[:i]
        return i

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
        extra = {}
        if getattr(self.model, "input_fitted", False):  # the engine's true torque the cradle carries
            extra["torque_input_true_nm"] = mean(self.te)
        # efficiency_true: the belt's (the CVT's) alone, what the host's interval should cover; the driveline
        # after it (RigParams driveline_loss_*) is recorded beside it: the gauge sees torque_secondary_true_nm
        # less driveline_loss_true_nm
        extra["driveline_loss_true_nm"] = mean(self.dl)
        return extra | {"efficiency_true": p_out / p_in if p_in > 0 else math.nan,
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
    run_enable_wired : the Nano's run-enable (D7) is in the kill chain (hardware/README.md; the shipped rig:
        ``[limits] supervisor_timeout_s`` > 0): the engine runs only while the host's polls keep it on
    brake_hold_relay : K3 fitted (rig.toml ``actuator.brake_hold_relay``); None: the physics' default
    pace : N when the simulation runs at N x real time on a real-time loop (the live UI); 1 otherwise
    bme280_address : the simulated BME280 on the bus (rig.toml ``[ambient] sensor = "bme280"``); None: none fitted
    """

    def __init__(self, now_s, *, seed: int = 0, params=None, protocol: str = "v2",
                 faults: BusFaults | None = None, clock_offset_us: int = 0, clock_ppm: float = 0.0,
                 full_stroke_s: float = 8.0, run_enable_wired: bool = False, brake_hold_relay: bool | None = None,
                 pace: float = 1.0, bme280_address: int | None = None, bme280_seed: int | None = None,
                 firmware_elf: dict | None = None) -> None:
        from dyno.sim.physics import RigModel  # the physics is the slow import; only when simulating

        self.model = RigModel(params, seed=seed)
        if brake_hold_relay is not None:  # K3: wiring, as rig.toml declares it
            self.model.brake_hold_relay = brake_hold_relay
        # Paced at N x real time on a real-time loop (dyno ui --speed N): each real-time poll spans N x more
        # rig time, so the ring holds the same span of rig time it has at 1x (64 events ~ 0.28 s of rig
        # events; otherwise a poll gap of a few ms overflows it: an artefact of pacing, not the link), and
        # the Nano's heartbeat keeps its real-time timeout
        ring = max(64, math.ceil(64 * pace))
        d7_wired = run_enable_wired and protocol == "v2"  # (the Nano's supervisor: v2 firmware)

        def _d7(on: bool, t_s: float, cause: str) -> None:
            self.model.nano_enable = on
        if firmware_elf is not None:  # the Nano's own ELF in simavr (firmware in the loop)
            from dyno.sim.elf_firmware import ElfFirmware

            self.firmware = ElfFirmware(firmware_elf["elf"], i2c_khz=firmware_elf["i2c_khz"],
                                        address=firmware_elf["address"], input_fitted=self.model.input_fitted,
                                        on_run_enable=_d7 if d7_wired else None,
                                        events_ahead=self.model.events_ahead,
                                        bounce_within_s=self.model.params.hall_bounce_max_s)
        else:
            self.firmware = EmulatedFirmware(protocol, clock_offset_us=clock_offset_us, clock_ppm=clock_ppm,
                                             input_fitted=self.model.input_fitted, ring_capacity=ring,
                                             pace=max(1.0, pace), on_run_enable=_d7 if d7_wired else None)
        self.bus = SimSMBus(self.model, self.firmware, now_s, faults, seed=seed)
        self._pull_until_s: float | None = None
        self.bus.after_step = self._operator
        if bme280_address is not None:  # the simulated air sensor, only when the rig file fits one
            from dyno.sim.bme280_chip import SimBME280

            self.bus.devices[bme280_address] = SimBME280(self.model.world, seed if bme280_seed is None else bme280_seed,
                                                         getattr(self.model.params, "bme280_temp_bias_c", 0.0))
        if d7_wired:
            self.model.nano_enable = False  # off until the host's limits arrive
        self.actuators = SimActuators(self.model, full_stroke_s=full_stroke_s, sync=self.bus.sync)
        self.truth = TruthRecorder(self.model)
        self.protocol = protocol

    def close(self) -> None:
        """End what the simulated rig started (the simavr harness of ``--firmware-elf``)."""
        close = getattr(self.firmware, "close", None)
        if close is not None:
            close()

    def start_engine(self) -> None:
        """The operator pulls the starter cord; with the kill chain still open (the Nano's run-enable not yet on),
        pulls again at every step for :data:`OPERATOR_PULLS_S`, as a person at the cord does."""
        self.model.start_engine()
        if not self.model.engine_running:
            self._pull_until_s = self.model.t_s + OPERATOR_PULLS_S

    def _operator(self) -> None:
        """After each physics step: the operator still at the cord."""
        if self._pull_until_s is None:
            return
        if self.model.engine_running or self.model.t_s > self._pull_until_s:
            self._pull_until_s = None
        else:
            self.model.start_engine()

    def audit(self, raw: bytes) -> bool:
        """True if ``raw`` is byte-for-byte a frame the device really served."""
        if self.firmware.protocol == "v0":
            return raw in self.firmware.served_v0
        return self.firmware.served.get(raw[3]) == raw
