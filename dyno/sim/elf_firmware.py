"""The Nano's real firmware in the simulated rig: its ELF in simavr between the physics and the host.

:class:`ElfFirmware` stands where :class:`dyno.sim.device.EmulatedFirmware` stands in :class:`dyno.sim.bus.SimSMBus`:
the physics' sensor events drive the ELF's pins, and the host's I2C transactions reach its TWI slave, through the
harness (``firmware/sim/harness.c`` in ``--plant`` mode, ``firmware/sim/plant.c``):

* each Hall edge of the physics (the engine's firing ripple included: the edge times are the shaft's) pulls
  the sensor's line low for the magnet's arc, 5 % of the last period (at most :data:`MAX_PULSE_US`);
* each AD7171 conversion of the physics (brake side, and engine side where fitted) is presented on DOUT/RDY
  with its own code and status, as the converter codes it;
* the run-enable (D7, read as the kill chain reads it: the level, or the charge pump of the old-bootloader
  build) feeds the physics' kill chain (``model.nano_enable``) at every :data:`LOCKSTEP_S` of simulated time.

Time is simavr's cycle clock in lockstep with the physics: the harness runs only as far as the physics has
been stepped, so a run is reproducible per seed whatever the machine's speed (no wall clock anywhere).
"""

from __future__ import annotations

import errno
import os
import subprocess
import tempfile
import time
from pathlib import Path

from dyno.errors import DynoError

#: the physics' cell (dyno.sim.physics: inputs act from the next cell): the run-enable is read this often
LOCKSTEP_S = 0.004
#: a transfer's sensor events are handed to the pins before it runs (the ISRs fire during a transfer): this far
#: ahead of the host's time, enough for a 100-byte transfer at 100 kHz (the inputs of those cells are fixed then)
TRANSFER_LOOKAHEAD_S = 0.010
#: one ``ev`` line's events at most this long (the harness reads lines of 64 KiB)
EV_LINE_CHARS = 60_000
#: a Hall sensor's pulse is the magnet's arc, 5 % of a turn; never longer than this
MAX_PULSE_US = 2000.0
FIRST_PULSE_US = 500.0
#: an edge of the physics this soon after the start of its sensor's last pulse is that pulse's bounce (the
#: physics' bounce edge comes 50-500 us after its edge: ``hall_bounce_max_s``); inside the pulse the line rings
#: high this long and falls, after it the line spikes low as long.  A real edge never comes that soon (one turn
#: in 0.5 ms is 120,000 rpm), however fast the shaft speeds up: a secondary starting from a crawl (a turn in
#: seconds) and engaging within the next turn gives real edges, each its own pulse
BOUNCE_WITHIN_S = 500e-6
BOUNCE_HIGH_US = 20.0
#: the Nano is powered (and its sketch set up: its TWI slave answers) this long before the run's time zero, as
#: on the rig, where it boots when the rig is powered, before the Pi starts a run
POWERED_BEFORE_S = 0.5
_CHANNEL_PIN = {"primary": "h0", "secondary": "h1", "adc": "a0", "input": "a1"}
REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_HARNESS = REPO_ROOT / "firmware" / "build" / "harness"


class FirmwareElfError(DynoError, RuntimeError):
    """The ELF or the harness is missing, or the harness died."""


def find_harness(path: str | os.PathLike | None = None) -> Path:
    """The simavr harness: ``path``, ``$DYNO_SIM_HARNESS``, or the repository's build."""
    p = Path(path or os.environ.get("DYNO_SIM_HARNESS") or DEFAULT_HARNESS)
    if not p.is_file():
        raise FirmwareElfError(f"simavr harness not found at {p} (build it with `make -C firmware sim`)")
    return p


def elf_spec(elf, rig_cfg, protocol: str) -> dict | None:
    """``--firmware-elf``: the ELF and the link it is reached by (the rig file's I2C address and clock), or None
    without one; a rig file or protocol the harness cannot serve is refused in one line."""
    if elf is None:
        return None
    from dyno.errors import ConfigError

    if rig_cfg.transport != "i2c":
        raise ConfigError(str(rig_cfg.path), "transport", "--firmware-elf runs the firmware's I2C link; "
                          f"this rig file's link is {rig_cfg.transport}")
    if protocol != "v2":
        raise ConfigError("command line", "--protocol", "--firmware-elf runs the v2 firmware")
    if not Path(elf).is_file():
        raise ConfigError(str(elf), "--firmware-elf", "no such file (build it: make -C firmware sim)")
    return {"elf": Path(elf), "i2c_khz": max(1, round(rig_cfg.i2c.bus_speed_hz / 1000)),
            "address": rig_cfg.i2c.firmware_address}


class ElfFirmware:
    """The firmware ELF as the simulated rig's Nano (the interface of :class:`dyno.sim.device.EmulatedFirmware`
    that the bus and the drills use: ``capture``, ``write``/``read``, ``reset``, ``service``, ``running``).

    Parameters
    ----------
    elf : the firmware ELF (``firmware/build/dyno_nano.elf``)
    i2c_khz : the rig file's bus clock (the harness's master clocks the transfer at it, in simulated time)
    address : the firmware's I2C address
    input_fitted : the engine-side AD7171 is wired (its pins driven; the host enables it)
    on_run_enable : ``f(on, t_s, cause)``: the wiring behind D7 (the physics' kill chain)
    bounce_within_s : an edge this soon after its sensor's last pulse started is that pulse's bounce (the
        physics' ``hall_bounce_max_s``)
    """

    protocol = "v2"

    def __init__(self, elf, *, i2c_khz: int = 100, address: int = 0x03, input_fitted: bool = False,
                 on_run_enable=None, events_ahead=None, harness=None, bounce_within_s: float = BOUNCE_WITHIN_S) -> None:
        self.elf = Path(elf)
        if not self.elf.is_file():
            raise FirmwareElfError(f"firmware ELF not found: {self.elf}")
        args = [str(find_harness(harness)), str(self.elf), "--plant", "--primary-rpm", "0", "--secondary-rpm", "0",
                "--adc-hz", "0", "--i2c-khz", str(int(i2c_khz)), "--addr", str(int(address))]
        if input_fitted:
            args += ["--input-hz", "1"]  # (its pins only: in --plant mode the physics makes its conversions)
        self._stderr = tempfile.TemporaryFile(mode="w+")
        self._proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr,
                                      text=True, bufsize=1)
        self.input_fitted = bool(input_fitted)
        self.on_run_enable = on_run_enable
        self._events_ahead = events_ahead  # f(until_s) -> the physics' events up to then (not consumed)
        self._sent_until_s = 0.0  # events up to here are already on their way to the pins
        self.t_s = 0.0  # the harness's simulated time, less POWERED_BEFORE_S (the physics' time)
        self.boot_id = 1  # (counted here for the serial bootloader's noise seed; the frames carry the ELF's)
        self.boot_count = 0
        self.served: dict[int, bytes] = {}  # seq -> the frame as last read (audits)
        self.served_v0: list = []
        self.events_generated = 0  # sensor events handed to the ELF's pins
        self.events_by_channel: dict[str, int] = {}  # the same, per physics channel (the truth of lossless)
        self.late_events = 0  # events the ELF's clock had already passed (a sign of a lockstep bug)
        self.run_enable_log: list[tuple[float, bool, str]] = []  # (sim t, D7 on, cause): the truth
        self._on = False
        self._outstanding: list[tuple[str, float | None]] = []  # commands sent whose replies are not read yet
        self._pending: list[str] = []
        self._write: bytes | None = None
        self._bounce_within_us = float(bounce_within_s) * 1e6
        self._last_edge_us: dict[str, float] = {}
        self._period_us: dict[str, float] = {}
        self.transactions = 0
        self.wait_s = 0.0  # wall time spent waiting on the harness (simavr's cycles and the pipe)
        self.round_trips = 0
        self._us = lambda t_s: (t_s + POWERED_BEFORE_S) * 1e6  # physics time -> the MCU's clock
        if self._cmds(f"run {self._us(0.0):.3f}")[0].split()[:1] != ["ok"]:
            raise FirmwareElfError(f"simavr harness did not start: {self._stderr_tail()}")

    # --- the harness ----------------------------------------------------------------------------
    def _cmds(self, *lines: str) -> list[str]:
        self._drain()
        proc = self._proc
        if proc.poll() is not None:
            raise FirmwareElfError(f"simavr harness exited ({proc.returncode}): {self._stderr_tail()}")
        t0 = time.perf_counter()
        try:
            proc.stdin.write("".join(line + "\n" for line in lines))
            proc.stdin.flush()
            replies = [proc.stdout.readline() for _ in lines]
            self.wait_s += time.perf_counter() - t0
            self.round_trips += 1
        except (BrokenPipeError, OSError) as exc:
            raise FirmwareElfError(f"simavr harness pipe broke: {exc}: {self._stderr_tail()}") from exc
        if not all(replies):
            raise FirmwareElfError(f"simavr harness closed its output: {self._stderr_tail()}")
        return [r.strip() for r in replies]

    def _stderr_tail(self) -> str:
        self._stderr.flush()
        self._stderr.seek(0)
        return self._stderr.read()[-500:]

    def _ev_lines(self) -> list[str]:
        """The events waiting for the pins as ``ev`` lines (several when a long catch-up queued more than the
        harness's line holds)."""
        if not self._pending:
            return []
        batches, batch, size = [], [], 0
        for item in self._pending:
            if size + len(item) > EV_LINE_CHARS and batch:
                batches.append("ev " + ",".join(batch))
                batch, size = [], 0
            batch.append(item)
            size += len(item) + 1
        batches.append("ev " + ",".join(batch))
        self._pending.clear()
        return batches

    def _with_events(self, line: str) -> str:
        """``line``, preceded by the events waiting for the pins (one pipe round trip)."""
        *evs, reply = self._cmds(*self._ev_lines(), line)
        for ev in evs:
            if not ev.startswith("ok "):
                raise FirmwareElfError(f"simavr harness: ev: {ev}")
            self.late_events += int(ev.split()[1])
        return reply

    def _run_to(self, t_s: float) -> None:
        """The MCU runs to ``t_s`` with the events queued for its pins; the run-enable's changes reach the kill chain
        at once.  (Not pipelined: sending the next cell before reading this one's reply bought no time here, and
        while the host is frozen nothing else reads the replies, so a Nano cut would reach the physics late.)"""
        t_s = max(t_s, self.t_s)
        lines = self._ev_lines() + [f"run {self._us(t_s):.3f}"]
        proc = self._proc
        if proc.poll() is not None:
            raise FirmwareElfError(f"simavr harness exited ({proc.returncode}): {self._stderr_tail()}")
        try:
            proc.stdin.write("".join(line + "\n" for line in lines))
            proc.stdin.flush()
        except (BrokenPipeError, OSError) as exc:
            raise FirmwareElfError(f"simavr harness pipe broke: {exc}: {self._stderr_tail()}") from exc
        self._outstanding += [("ev", None)] * (len(lines) - 1) + [("run", t_s)]
        self.t_s = t_s
        self._drain()

    def _drain(self) -> None:
        """Read the replies of the commands sent ahead, in order, and act on them."""
        if not self._outstanding:
            return
        t0 = time.perf_counter()
        outstanding, self._outstanding = self._outstanding, []
        for kind, t_s in outstanding:
            reply = self._proc.stdout.readline()
            if not reply:
                raise FirmwareElfError(f"simavr harness closed its output: {self._stderr_tail()}")
            fields = reply.split()
            if kind == "ev":
                if fields[:1] != ["ok"]:
                    raise FirmwareElfError(f"simavr harness: ev: {reply.strip()}")
                self.late_events += int(fields[1])
                continue
            if len(fields) != 4 or fields[0] != "ok":
                raise FirmwareElfError(f"simavr harness: run: {reply.strip()}")
            # the run-enable as the kill chain reads it: every change since the last run, then its level then
            if fields[3] != "-":
                for item in fields[3].split(","):
                    t_us, level = item.split(":")
                    self._set_enable(bool(int(level)), max(0.0, float(t_us) * 1e-6 - POWERED_BEFORE_S))
            self._set_enable(bool(int(fields[2])), t_s)
        self.wait_s += time.perf_counter() - t0
        self.round_trips += 1

    def _set_enable(self, on: bool, t_s: float) -> None:
        if on == self._on:
            return
        self._on = on
        self.run_enable_log.append((t_s, on, "on" if on else "nano"))
        if self.on_run_enable is not None:
            self.on_run_enable(on, t_s, "on" if on else "nano")

    def close(self) -> None:
        if self._proc.poll() is None:
            try:
                self._cmds("quit")
            except FirmwareElfError:
                pass
            try:
                self._proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._proc.kill()
        self._stderr.close()

    def report(self) -> dict:
        """The run's ``firmware`` document: the ELF, its events and the harness's own counts."""
        doc = {"elf": str(self.elf), "events_to_pins": dict(self.events_by_channel), "late_events": self.late_events,
               "transactions": self.transactions, "sim_s": self.t_s, "run_enable_changes": len(self.run_enable_log)}
        try:
            st = self.stats()
        except FirmwareElfError as exc:
            doc["harness_error"] = str(exc)
            return doc
        doc["harness"] = {"edges": [h["edges"] for h in st["hall"]], "crashed": st["crashed"], **st.get("plant", {}),
                          "sim_per_wall": st.get("sim_per_wall")}
        # where the time went: simavr's own cycles (the harness's wall inside its run loop), and the rest of the
        # waits on it (the pipe and the hand-over between the processes)
        doc["time"] = {"wait_on_harness_s": round(self.wait_s, 3), "simavr_s": st.get("wall_s"),
                       "round_trips": self.round_trips}
        return doc

    def stats(self) -> dict:
        import json

        return json.loads(self._with_events("stats"))

    # --- what the bus and the physics call ----------------------------------------------------------
    def capture(self, channel: str, t_s: float, code: int = 0, status: int = 0) -> None:
        if t_s <= self._sent_until_s:
            return  # (handed over ahead of a transfer)
        self._send(channel, t_s, code, status)

    def _send(self, channel: str, t_s: float, code: int, status: int) -> None:
        pin = _CHANNEL_PIN[channel]
        if pin == "a1" and not self.input_fitted:
            return
        t_us = self._us(t_s)
        if pin[0] == "h":
            last = self._last_edge_us.get(pin)
            period = self._period_us.get(pin)
            width = FIRST_PULSE_US if period is None else min(MAX_PULSE_US, 0.05 * period)
            if last is not None and t_us - last <= self._bounce_within_us:  # the last pulse's bounce
                if t_us < last + width:  # inside the pulse: the line rings high
                    self._pending.append(f"b{pin[1]}:{t_us:.3f}:{BOUNCE_HIGH_US:.1f}")
                else:  # just after it: a short low spike
                    self._pending.append(f"{pin}:{t_us:.3f}:{BOUNCE_HIGH_US:.1f}")
            else:
                if last is not None:
                    self._period_us[pin] = t_us - last
                self._last_edge_us[pin] = t_us
                self._pending.append(f"{pin}:{t_us:.3f}:{width:.1f}")
        else:
            self._pending.append(f"{pin}:{t_us:.3f}:{int(code) & 0xFFFF}:{int(status) & 0xFF}")
        self.events_generated += 1
        self.events_by_channel[channel] = self.events_by_channel.get(channel, 0) + 1

    def next_deadline_s(self) -> float:
        """The bus steps the physics to here and calls :meth:`service`: the run-enable is read every cell."""
        return self.t_s + LOCKSTEP_S

    def service(self, now_s: float) -> None:
        self._run_to(now_s)

    @property
    def run_enable(self) -> bool:
        self._drain()
        return self._on

    def running(self, now_s: float) -> bool:
        return True  # (the harness starts the sketch at once, as Optiboot does after a watchdog reset)

    def reset(self, now_s: float, cause: int = 0x08) -> None:
        self._run_to(now_s)
        reply = self._cmds(f"reset {cause & 0xFF:02x}")[0]
        if reply != "ok":
            raise FirmwareElfError(f"simavr harness: reset: {reply}")
        self.boot_id = (self.boot_id + 1) & 0xFFFF
        self.boot_count += 1
        self._run_to(now_s)  # (the reset's effect on the run-enable)
        self._drain()

    def write(self, data: bytes, now_s: float) -> None:
        self._write = (self._write or b"") + bytes(data)

    def read(self, n: int, now_s: float) -> bytes:
        data = self._transfer(n, now_s)
        if len(data) >= 4 and 4 <= data[1] <= len(data):
            self.served[data[3]] = data[: data[1]]
        return data

    def end_transaction(self, now_s: float) -> None:
        """A transaction that only wrote (a command): it goes out now."""
        if self._write is not None:
            self._transfer(0, now_s)

    def _transfer(self, n: int, now_s: float) -> bytes:
        request, self._write = self._write, None
        t_s = max(now_s, self.t_s)
        if self._events_ahead is not None:
            until_s = t_s + TRANSFER_LOOKAHEAD_S
            for ev in self._events_ahead(until_s):
                if ev.t_s > self._sent_until_s:
                    self._send(ev.channel, ev.t_s, ev.code, ev.status)
            self._sent_until_s = max(self._sent_until_s, until_s)
        reply = self._with_events(f"xfer {(request or b'').hex() or '-'} {int(n)} {self._us(t_s):.3f}")
        self.t_s = t_s
        self.transactions += 1
        if reply == "nack":
            raise OSError(errno.EREMOTEIO, "NACK (the firmware's TWI slave)")
        if reply in ("timeout", "busheld"):
            raise OSError(errno.ETIMEDOUT, f"{reply} (the firmware's TWI slave)")
        if not reply.startswith("ok "):
            raise FirmwareElfError(f"simavr harness: xfer: {reply}")
        hexdata, t_us = reply[3:].split()
        self.t_s = max(self.t_s, float(t_us) * 1e-6 - POWERED_BEFORE_S)  # (the transfer took the bus's time)
        return b"" if hexdata == "-" else bytes.fromhex(hexdata)
