"""A simulated I2C bus speaking the same ``i2c_rdwr`` call as smbus2.

Devices: the emulated firmware at 0x03, an MLX90614-like rotor thermometer
at 0x5A and, when the rig declares one, a BME280 (:mod:`dyno.sim.bme280_chip`).  Before every transaction the rig physics is advanced to the current
(injected) time and its sensor events are captured by the emulated firmware,
so what the host reads is exactly what it would read on the rig at that
moment.  Fault injection (bit errors, NACKs, timeouts, truncated reads, device
resets) happens here, between the device and the host, like a noisy cable.
"""

from __future__ import annotations

import ctypes
import errno
import threading
from dataclasses import dataclass, field

import numpy as np

from dyno.hw.thermometer import smbus_pec  # the host's own PEC: one definition

FIRMWARE_ADDRESS = 0x03
THERMOMETER_ADDRESS = 0x5A
I2C_M_RD = 0x0001


@dataclass
class BusFaults:
    """Fault-injection knobs (probabilities per transaction unless stated)."""

    bit_error_rate: float = 0.0  # per bit, on bytes in both directions
    nack_rate: float = 0.0  # address not acknowledged: nothing reaches the device
    timeout_rate: float = 0.0  # the transfer hangs after the device saw it
    truncate_rate: float = 0.0  # the device stops sending part-way: the rest reads 0xFF
    reset_times_s: list[float] = field(default_factory=list)  # device resets at these times

    @classmethod
    def mixed(cls, fraction: float) -> "BusFaults":
        """About ``fraction`` of transfers corrupted, split over the fault kinds.

        Bit errors at 1/256 per bit hit ~12 % of 32-byte reads... so scale the
        BER to give ``fraction/3`` corrupted reads, plus NACKs and truncations.
        """
        per_kind = fraction / 3.0
        ber = 1.0 - (1.0 - per_kind) ** (1.0 / 288)  # 36 bytes per poll on the wire
        return cls(bit_error_rate=ber, nack_rate=per_kind / 2, timeout_rate=per_kind / 2,
                   truncate_rate=per_kind)


class SimSMBus:
    """SMBus-like object: ``i2c_rdwr(*msgs)`` with smbus2 ``i2c_msg`` messages."""

    def __init__(self, rig, firmware, now_s, faults: BusFaults | None = None, seed: int = 0) -> None:
        self.rig = rig
        self.firmware = firmware
        self.now_s = now_s
        self.faults = faults or BusFaults()
        self.rng = np.random.default_rng(seed + 7919)
        self.injected = {"bit_error": 0, "nack": 0, "timeout": 0, "truncate": 0, "reset": 0}
        self._resets = sorted(self.faults.reset_times_s)
        self._thermo_cmd = None
        # The physics is stepped by whoever asks first: the poller, an actuator command, or
        # the watchdog thread safing the rig while the loop is stalled.  One at a time.
        self._lock = threading.RLock()
        self._stepping = False  # inside rig.step: a re-entrant sync (a signal handler's safe state) waits
        self._rng_thermo = np.random.default_rng(seed + 104729)
        # drills: the cable falls out (every device NACKs); the thermometer stops answering,
        # or answers with one frozen word forever
        self.lost = False
        self.thermometer_lost = False
        self.thermometer_stuck = False
        self._thermo_stuck_word: bytes | None = None
        self.after_step = None  # callable() after each physics step (the simulated operator at the cord)
        self.devices: dict = {}  # address -> device with .transaction(msgs) (the BME280 when rig.toml fits one)

    def schedule_reset(self, t_s: float) -> None:
        """A device reset at simulation time ``t_s`` (a drill)."""
        self._resets = sorted([*self._resets, t_s])

    # --- physics ---------------------------------------------------------------------
    def sync(self) -> None:
        """Advance the physics to now and let the firmware capture what happened."""
        with self._lock:
            self._sync()

    def _sync(self) -> None:
        now = self.now_s()
        while self._resets and self._resets[0] <= now:
            t_reset = self._resets.pop(0)
            self._advance(t_reset)
            self.firmware.reset(t_reset)
            self.injected["reset"] += 1
        self._advance(now)

    def _advance(self, t_s: float) -> None:
        if self._stepping:  # (a signal handler inside a step: its inputs act from the step's end)
            return
        # The Nano's heartbeat expires at a known instant: the physics is stepped to it, the output drops
        # there, and the kill chain acts from then on (not from the next poll, which may never come).
        deadline = getattr(self.firmware, "next_deadline_s", lambda: None)()
        while deadline is not None and deadline < t_s:
            self._step_to(deadline)
            self.firmware.service(deadline)
            nxt = self.firmware.next_deadline_s()
            if nxt is not None and nxt <= deadline:
                break
            deadline = nxt
        self._step_to(t_s)

    def _step_to(self, t_s: float) -> None:
        dt = t_s - self.rig.t_s
        if dt <= 0:
            return
        capture = self.firmware.capture
        self._stepping = True
        try:
            for ev in self.rig.step(dt):
                capture(ev.channel, ev.t_s, ev.code, ev.status)
        finally:
            self._stepping = False
        if self.after_step is not None:
            self.after_step()

    # --- smbus2 API ---------------------------------------------------------------------
    def i2c_rdwr(self, *msgs) -> None:
        with self._lock:
            self._i2c_rdwr(*msgs)

    def _i2c_rdwr(self, *msgs) -> None:
        self._sync()
        now = self.now_s()
        addr = msgs[0].addr
        if self.lost:
            raise OSError(errno.EREMOTEIO, "NACK: bus lost (drill)")
        if addr == FIRMWARE_ADDRESS:
            self._firmware_transaction(msgs, now)
        elif addr == THERMOMETER_ADDRESS:
            self._thermometer_transaction(msgs)
        elif addr in self.devices:
            self.devices[addr].transaction(msgs)
        else:
            raise OSError(errno.ENXIO, f"no device at 0x{addr:02x}")

    def close(self) -> None:
        pass

    def _flip(self, data: bytes) -> bytes:
        ber = self.faults.bit_error_rate
        if ber <= 0:
            return data
        nbits = len(data) * 8
        flips = np.flatnonzero(self.rng.random(nbits) < ber)
        if flips.size == 0:
            return data
        out = bytearray(data)
        for bit in flips:
            out[bit >> 3] ^= 0x80 >> (bit & 7)
        self.injected["bit_error"] += 1
        return bytes(out)

    def _firmware_transaction(self, msgs, now: float) -> None:
        f = self.faults
        rng = self.rng
        if not self.firmware.running(now):  # its bootloader: the I2C slave is not up yet
            raise OSError(errno.EREMOTEIO, "NACK (the Nano's bootloader after a reset)")
        if f.nack_rate and rng.random() < f.nack_rate:
            self.injected["nack"] += 1
            raise OSError(errno.EREMOTEIO, "NACK (injected)")
        for msg in msgs:
            if msg.flags & I2C_M_RD:
                data = self.firmware.read(msg.len, now)
                if f.truncate_rate and rng.random() < f.truncate_rate:
                    cut = int(rng.integers(0, msg.len))
                    data = data[:cut] + b"\xff" * (msg.len - cut)
                    self.injected["truncate"] += 1
                data = self._flip(data)
                ctypes.memmove(msg.buf, data, msg.len)
            else:
                self.firmware.write(self._flip(bytes(msg)), now)
        end = getattr(self.firmware, "end_transaction", None)
        if end is not None:  # (the ELF's slave: a command written alone goes out as its own transfer)
            end(now)
        if f.timeout_rate and rng.random() < f.timeout_rate:
            self.injected["timeout"] += 1
            raise OSError(errno.ETIMEDOUT, "timeout (injected)")

    def _thermometer_transaction(self, msgs) -> None:
        """MLX90614 SMBus read-word with PEC (object temperature at RAM 0x07).

        The object temperature is the rotor's seen through the sensor's lag
        (``RigModel.thermometer_c``) plus read noise, coded in 0.02 K steps.
        """
        if self.thermometer_lost:
            raise OSError(errno.EREMOTEIO, "MLX90614: NACK (drill thermometer-lost)")
        cmd = None
        for msg in msgs:
            if msg.flags & I2C_M_RD:
                if cmd == 0x07 and self.thermometer_stuck and self._thermo_stuck_word is not None:
                    ctypes.memmove(msg.buf, self._thermo_stuck_word[: msg.len], min(3, msg.len))
                    continue
                if cmd == 0x07:
                    temp_c = float(getattr(self.rig, "thermometer_c", self.rig.rotor_temp_c))
                    noise = getattr(self.rig.params, "thermometer_noise_c", 0.0)
                    if noise:
                        temp_c += noise * float(self._rng_thermo.standard_normal())
                elif cmd == 0x06:
                    temp_c = float(getattr(self.rig.params, "ambient_temp_c", 25.0))
                else:
                    raise OSError(errno.EREMOTEIO, f"MLX90614: unsupported command {cmd}")
                raw = max(0, min(0x7FFF, round((temp_c + 273.15) / 0.02)))
                lsb, msb = raw & 0xFF, raw >> 8
                a = THERMOMETER_ADDRESS << 1
                pec = smbus_pec(bytes([a, cmd, a | 1, lsb, msb]))
                word = bytes([lsb, msb, pec])
                if cmd == 0x07 and self.thermometer_stuck:
                    self._thermo_stuck_word = word  # frozen from this read on
                ctypes.memmove(msg.buf, word[: msg.len], min(3, msg.len))
            else:
                data = bytes(msg)
                cmd = data[0] if data else None
