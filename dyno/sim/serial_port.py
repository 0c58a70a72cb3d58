"""The simulated Nano on USB serial: a pyserial-like port in front of the emulated firmware.

What the real link does that a test must meet (docs/install-pi.md, "USB serial"):

* **Opening the port resets the Nano.**  The USB-serial chip's DTR line is wired through a capacitor to RESET:
  every open pulses it.  The bootloader (Optiboot) then listens for an upload for about a second
  (:data:`dyno.sim.device.BOOTLOADER_S`) and the sketch starts — until then nothing answers.
  The host must wait for the new boot, not assume it: :func:`dyno.transports.serial.open_serial`.
* **The bootloader talks during its window.**  A real one is not silent: its LED flashes couple onto the line,
  and a clone's bootloader prints; here bytes (0x00 among them) come for most of the window.  A byte the
  host sends into the window is taken for upload traffic (counted, ``taken_by_bootloader``: a real Optiboot
  would read STK500 commands in it).
* **Packets** are COBS-encoded and end in 0x00 (docs/protocol.md, "v1 and v2 over USB serial"); the device
  answers POLL, ACK_POLL, INFO and CAPS with one frame each, unpadded, and nothing else.
* A read with nothing to read waits its ``timeout`` (on the injected clock), as pyserial's does.
"""

from __future__ import annotations

from dyno.errors import FrameError
from dyno.protocol import v1, v2

#: the ops that get one frame back
ANSWERED = (v1.OP_POLL, v1.OP_ACK_POLL, v1.OP_INFO, v2.OP_CAPS)


class SimSerialPort:
    """``write``, ``read(n)``, ``in_waiting``, ``timeout``, ``close`` over ``sim`` (a :class:`dyno.sim.rig.SimRig`).

    Constructing it is opening the port: the emulated firmware resets (cause: external reset) at once.
    ``clock`` (``now``, ``sleep``) is the simulation's; ``reset_on_open=False`` is a Nano whose auto-reset is
    cut (the capacitor removed).
    """

    def __init__(self, sim, clock, *, reset_on_open: bool = True, bootloader_talks_s: float | None = None) -> None:
        from dyno.sim.device import BOOTLOADER_S
        from dyno.transports.serial import CobsDeframer

        self.sim = sim
        self.clock = clock
        self.timeout = 0.05
        self._out = bytearray()
        self._in = CobsDeframer(validate=None)
        self.resets = 0
        self.ignored_in_bootloader = 0
        self.taken_by_bootloader = 0  # host bytes that reached the bootloader during its window
        self.noise_bytes = 0  # bytes the bootloader put on the line
        self.closed = False
        self._noise: list[tuple[float, bytes]] = []  # (time, bytes) the bootloader sends, in time order
        if reset_on_open:  # DTR pulses RESET: an external reset, the bootloader's wait before the sketch
            sim.bus.sync()
            t = clock.now()
            sim.firmware.reset(t, cause=v2.CAUSE_EXTRF)
            self.resets += 1
            talks_s = BOOTLOADER_S - 0.1 if bootloader_talks_s is None else bootloader_talks_s
            self._noise = _bootloader_noise(t, talks_s, seed=sim.firmware.boot_id)

    def _deliver(self) -> None:
        now = self.clock.now()
        while self._noise and self._noise[0][0] <= now:
            chunk = self._noise.pop(0)[1]
            self._out += chunk
            self.noise_bytes += len(chunk)

    @property
    def in_waiting(self) -> int:
        self._deliver()
        return len(self._out)

    def write(self, data: bytes) -> int:
        if not self.sim.firmware.running(self.clock.now()):
            self.taken_by_bootloader += len(data)
        for packet in self._in.feed(bytes(data)):
            self._command(packet)
        return len(data)

    def _command(self, packet: bytes) -> None:
        now = self.clock.now()
        fw = self.sim.firmware
        if not fw.running(now):  # the bootloader reads the bytes as (bad) upload traffic, answers none
            self.ignored_in_bootloader += 1
            return
        proto = v2 if fw.protocol == "v2" else v1
        try:
            op = proto.decode_command(packet).op
        except FrameError:
            op = None  # ignored by the firmware: no answer
        self.sim.bus.sync()  # the physics up to now, the firmware's ring with it
        fw.write(packet, now)
        if op in ANSWERED:
            from dyno.transports.serial import DELIMITER, FRAME_MAX, cobs_encode

            frame = fw.read(FRAME_MAX, now)
            frame = frame[: frame[1]] if len(frame) > 1 and 0 < frame[1] <= FRAME_MAX else frame
            self._out += cobs_encode(frame) + DELIMITER

    def read(self, n: int = 1) -> bytes:
        self._deliver()
        if not self._out:
            if self.timeout:
                self.clock.sleep(self.timeout)
            self._deliver()
            if not self._out:
                return b""
        out = bytes(self._out[:n])
        del self._out[:n]
        return out

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.closed = True


def _bootloader_noise(t0_s: float, talks_s: float, *, seed: int) -> list[tuple[float, bytes]]:
    """What a bootloader puts on the line after a reset: a few bytes every 20 ms for ``talks_s``, zeros among
    them (so a receiver sees delimited garbage, and now and then a short COBS-valid chunk)."""
    import random

    rng = random.Random(seed)
    out = []
    n = max(0, int(talks_s / 0.02))
    for i in range(n):
        chunk = bytes(rng.choice((0, 0x30, 0x20, 0x14, 0x10, rng.randrange(256))) for _ in range(rng.randint(1, 6)))
        out.append((t0_s + 0.01 + i * 0.02, chunk))
    return out
