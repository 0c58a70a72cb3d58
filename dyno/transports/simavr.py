"""A transport to the real firmware ELF running in simavr (firmware in the loop).

The C harness (``firmware/sim/harness.c``, built by ``make -C firmware sim``) runs the
ELF with emulated Hall sensors and AD7171 and plays the I2C master; this class drives
it over a line protocol on its stdin/stdout.  Simulated time only moves when the host
says so (:meth:`SimavrTransport.advance_to`) and while a transfer is on the bus, so a
poll loop at 150 Hz of *simulated* time reproduces the rig's schedule whatever the
machine's speed.

Faults can be injected between the harness and the host (seeded, reproducible):
a bit flip in the frame read, a bit flip in the command written (the device then
ignores it), a truncated read, or a NACK reported after the device already sent the
frame.  All of them must end in a re-read, never in a lost or doubled event.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import tempfile
from collections import Counter
from pathlib import Path

from dyno.errors import DynoError
from dyno.transports.base import Transport, TransportFault

FAULT_KINDS = ("read_bitflip", "cmd_bitflip", "truncate", "nack")
# "abort": the master stops clocking halfway through the read (a killed host): the slave
# holds SDA until its 25 ms timeout releases the bus (transfers meanwhile: bus_held).
ALL_FAULT_KINDS = FAULT_KINDS + ("abort",)
REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_HARNESS = REPO_ROOT / "firmware" / "build" / "harness"


class HarnessError(DynoError, RuntimeError):
    """The simavr harness is missing, died, or answered nonsense."""


def find_harness(path: str | os.PathLike | None = None) -> Path:
    """The harness binary: ``path``, ``$DYNO_SIM_HARNESS``, or the repository build."""
    cand = path or os.environ.get("DYNO_SIM_HARNESS") or DEFAULT_HARNESS
    p = Path(cand)
    if not p.is_file():
        hint = " (build it with `make -C firmware sim`)" if p == DEFAULT_HARNESS else ""
        raise HarnessError(f"simavr harness not found at {p}{hint}")
    return p


class SimavrTransport(Transport):
    """``transfer(request, read_len)`` as one I2C transaction on the simulated bus."""

    name = "simavr"

    def __init__(self, elf: str | os.PathLike, *, harness: str | os.PathLike | None = None,
                 primary_rpm: float = 3800.0, secondary_rpm: float = 7600.0,
                 adc_code: int = 35145, adc_status: int = 0x05, adc_error_every: int = 0,
                 adc_hz: float = 125.0, bounce: bool = False, i2c_khz: int = 100,
                 address: int = 0x03, start_us: float = 50_000.0, profile: bool = False,
                 profile_from_us: float = 100_000.0, glitch_hz: float = 0.0, glitch_us: float = 20.0,
                 legacy_pullups: bool = False, input_hz: float = 0.0, enable_model: str = "auto",
                 fault_rate: float = 0.0, fault_kinds=FAULT_KINDS, seed: int = 0) -> None:
        super().__init__()
        elf = Path(elf)
        if not elf.is_file():
            raise HarnessError(f"firmware ELF not found: {elf}")
        if not 0.0 <= fault_rate <= 1.0:
            raise ValueError("fault_rate must be within 0..1")
        args = [str(find_harness(harness)), str(elf),
                "--primary-rpm", repr(float(primary_rpm)),
                "--secondary-rpm", repr(float(secondary_rpm)),
                "--adc-code", str(int(adc_code)), "--adc-status", str(int(adc_status)),
                "--adc-error-every", str(int(adc_error_every)), "--adc-hz", repr(float(adc_hz)),
                "--i2c-khz", str(int(i2c_khz)), "--addr", str(int(address)),
                "--start-us", repr(float(start_us)),
                "--profile-from-us", repr(float(profile_from_us)),
                "--glitch-hz", repr(float(glitch_hz)), "--glitch-us", repr(float(glitch_us))]
        if enable_model != "auto":  # how the harness reads the run-enable on PD7 (issue 37)
            args += ["--enable-model", str(enable_model)]
        if input_hz > 0:  # the engine-side input torque AD7171 on PB0/PB1 (issue 27)
            args += ["--input-hz", repr(float(input_hz))]
        if bounce:
            args.append("--bounce")
        if legacy_pullups:  # simavr's own pull-up handling, which stomps external drivers
            args.append("--legacy-pullups")
        if profile:
            args.append("--profile")
        # stderr to a file, not a pipe: simavr's warnings must never block the harness.
        self._stderr = tempfile.TemporaryFile(mode="w+")
        self._proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      stderr=self._stderr, text=True, bufsize=1)
        self.fault_rate = float(fault_rate)
        self.fault_kinds = tuple(fault_kinds)
        bad = set(self.fault_kinds) - set(ALL_FAULT_KINDS)
        if bad:
            raise ValueError(f"unknown fault kinds {sorted(bad)}; known: {','.join(ALL_FAULT_KINDS)}")
        self.bus_held = False
        self._rng = random.Random(seed)
        self.faults_injected: Counter = Counter()
        self.sim_time_us = 0.0
        self._pending_us: float | None = None

    # -- harness line protocol --------------------------------------------------
    def _cmd(self, line: str) -> str:
        proc = self._proc
        if proc.poll() is not None:
            raise HarnessError(f"harness exited ({proc.returncode}): {self._stderr_tail()}")
        try:
            proc.stdin.write(line + "\n")
            proc.stdin.flush()
            reply = proc.stdout.readline()
        except (BrokenPipeError, OSError) as exc:
            raise HarnessError(f"harness pipe broke: {exc}: {self._stderr_tail()}") from exc
        if not reply:
            raise HarnessError(f"harness closed its output: {self._stderr_tail()}")
        return reply.strip()

    def _stderr_tail(self) -> str:
        self._stderr.flush()
        self._stderr.seek(0)
        return self._stderr.read()[-500:]

    def advance_to(self, t_s: float) -> None:
        """Simulated time ``t_s`` has come (no-op if already past).

        Lazy: the harness runs there as part of the next command, so a poll costs one
        pipe round trip, not two (on a loaded machine each costs a scheduler slot).
        """
        self._pending_us = max(self._pending_us or 0.0, t_s * 1e6)

    def sync(self) -> float:
        """Run the simulation to the pending time now; returns simulated time in us."""
        reply = self._cmd(f"run {(self._pending_us or 0.0):.3f}")
        if not reply.startswith("ok"):
            raise HarnessError(f"run: {reply}")
        self._pending_us = None
        self.sim_time_us = float(reply.split()[1])
        return self.sim_time_us

    def generators(self, on: bool) -> None:
        """Start/stop the Hall and ADC generators (stop before draining the device)."""
        self.sync()
        if self._cmd("gen on" if on else "gen off") != "ok":
            raise HarnessError("gen")

    def reset_device(self, mcusr: int = 0x08) -> None:
        """Reset the MCU (RAM kept, as on hardware) with this cause in MCUSR (default WDRF)."""
        self.sync()
        if self._cmd(f"reset {mcusr & 0xFF:02x}") != "ok":
            raise HarnessError("reset")

    def harness_stats(self) -> dict:
        self.sync()
        return json.loads(self._cmd("stats"))

    def poke(self, addr: int, value: int) -> None:
        """Write one SRAM byte behind the firmware's back (tests of the harness's checks)."""
        self.sync()
        if self._cmd(f"poke {addr:x} {value & 0xFF:02x}") != "ok":
            raise HarnessError("poke")

    # -- Transport ------------------------------------------------------------------
    def _transfer(self, request: bytes, read_len: int) -> bytes:
        kind = None
        if self.fault_rate and self._rng.random() < self.fault_rate and not self.bus_held:
            kind = self._rng.choice(self.fault_kinds)
            if kind == "cmd_bitflip" and not request:
                kind = "read_bitflip"  # v0 writes nothing
            self.faults_injected[kind] += 1
        if kind == "cmd_bitflip":
            request = _flip(request, self._rng)
        at = "" if self._pending_us is None else f" {self._pending_us:.3f}"
        self._pending_us = None
        verb = "abort" if kind == "abort" else "xfer"
        reply = self._cmd(f"{verb} {request.hex() or '-'} {int(read_len)}{at}")
        self.bus_held = kind == "abort" or reply == "busheld"
        if kind == "abort":
            raise TransportFault("timeout", "master aborted mid-read (injected)")
        if reply == "busheld":
            raise TransportFault("bus_held", "SDA held low since an aborted transfer")
        if reply == "nack":
            raise TransportFault("nack", "device did not acknowledge")
        if reply == "timeout":
            raise TransportFault("timeout", "device held SCL low for 25 ms")
        if not reply.startswith("ok "):
            raise HarnessError(f"xfer: {reply}")
        hexdata = reply[3:]
        data = b"" if hexdata == "-" else bytes.fromhex(hexdata)
        if kind == "read_bitflip" and data:
            data = _flip(data, self._rng)
        elif kind == "truncate" and data:
            data = data[: self._rng.randrange(len(data))]
        elif kind == "nack":
            # The device sent the frame (and now counts it as sent); the host never
            # got it. The acknowledge protocol must make it come again.
            raise TransportFault("nack", "injected")
        return data

    def close(self) -> None:
        proc = self._proc
        if proc.poll() is None:
            try:
                proc.stdin.write("quit\n")
                proc.stdin.flush()
            except OSError:
                pass
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for f in (proc.stdin, proc.stdout, self._stderr):
            try:
                f.close()
            except OSError:
                pass


def _flip(data: bytes, rng: random.Random) -> bytes:
    buf = bytearray(data)
    i = rng.randrange(len(buf))
    buf[i] ^= 1 << rng.randrange(8)
    return bytes(buf)


def toolchain_missing() -> str | None:
    """Why firmware-in-the-loop cannot run here, or ``None`` if it can."""
    for tool in ("avr-gcc", "avr-g++", "make", "cc"):
        if shutil.which(tool) is None:
            return f"{tool} not found (apt-get install gcc-avr avr-libc binutils-avr make gcc)"
    if not Path("/usr/include/simavr/sim_avr.h").is_file():
        return "libsimavr headers not found (apt-get install libsimavr-dev libelf-dev)"
    if not Path("/usr/include/gelf.h").is_file():  # the harness reads the ELF's symbols
        return "libelf headers not found (apt-get install libelf-dev)"
    if not Path("/usr/share/arduino/hardware/arduino/avr/cores/arduino").is_dir():
        return "Arduino core not found (apt-get install arduino-core-avr)"
    return None


class SimavrSerialPort:
    """A pyserial-like port on the harness's UART0, in *simulated* time.

    ``read(n)`` waits up to ``timeout`` simulated seconds for the MCU to finish a packet
    (the harness runs the MCU meanwhile); ``now()`` is the simulated clock the serial
    transport's deadlines use.
    """

    def __init__(self, harness: SimavrTransport) -> None:
        self.h = harness
        self.timeout = 0.05
        self._buf = bytearray()

    def now(self) -> float:  # the Clock protocol (dyno.clock): simulated seconds
        return self.h.sim_time_us / 1e6

    @property
    def in_waiting(self) -> int:
        return len(self._buf)

    def write(self, data: bytes) -> int:
        h = self.h
        at = "" if h._pending_us is None else f" {h._pending_us:.3f}"
        h._pending_us = None
        if h._cmd(f"uwrite {bytes(data).hex() or '-'}{at}") != "ok":
            raise HarnessError("uwrite")
        return len(data)

    def read(self, n: int = 1) -> bytes:
        if not self._buf and self.timeout and self.timeout > 0:
            reply = self.h._cmd(f"uread {self.timeout * 1e6:.3f}")
            if not reply.startswith("ok "):
                raise HarnessError(f"uread: {reply}")
            _, t_us, hexdata = reply.split()
            self.h.sim_time_us = float(t_us)
            if hexdata != "-":
                self._buf += bytes.fromhex(hexdata)
        out = bytes(self._buf[:n])
        del self._buf[:n]
        return out


class SimavrSerialTransport(Transport):
    """The host's :class:`~dyno.transports.serial.SerialTransport` (COBS over USB serial)
    talking to the real firmware's UART in simavr; the harness controls as for I2C."""

    name = "simavr-serial"

    def __init__(self, elf, *, timeout_s: float = 0.05, **harness_kw) -> None:
        super().__init__()
        from dyno.transports.serial import SerialTransport

        self.harness = SimavrTransport(elf, **harness_kw)
        self.port = SimavrSerialPort(self.harness)
        self.serial = SerialTransport(self.port, timeout_s=timeout_s, clock=self.port)
        self.faults_injected = self.harness.faults_injected

    def _transfer(self, request: bytes, read_len: int) -> bytes:
        return self.serial.transfer(request, read_len)

    def advance_to(self, t_s: float) -> None:
        self.harness.advance_to(t_s)

    def generators(self, on: bool) -> None:
        self.harness.generators(on)

    def reset_device(self, mcusr: int = 0x08) -> None:
        self.harness.reset_device(mcusr)

    def harness_stats(self) -> dict:
        return self.harness.harness_stats()

    def close(self) -> None:
        self.harness.close()
