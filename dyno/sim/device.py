"""The firmware, emulated: sensor events in, protocol bytes out.

It behaves as docs/protocol.md says the Nano does (ring buffer with an
overflow counter, per-channel Hall debounce, frames frozen once sent and
retired only by a matching ACK_POLL, RESET flag and a new time epoch after a
reset) so the host decodes the simulated rig through exactly the path it uses
on the real one.  It speaks v2 (default: boot identity echoed in ACK_POLL, reset
cause, CRC-32C), v1, or ``protocol="v0"``, the thesis sketch's 20-byte frame.
For the same events, boot and commands its v2 bytes are the firmware's
(the golden vectors bind both to ``dyno.protocol.v2``).
"""

from __future__ import annotations

from collections import deque

from dyno.errors import FrameError
from dyno.protocol import v0, v1, v2
from dyno.sim.supervisor import NanoSupervisor

CHANNEL_TAG = {"primary": v1.CH_PRIMARY, "secondary": v1.CH_SECONDARY, "adc": v1.CH_ADC, "input": v2.CH_INPUT}
INPUT_RATE_MHZ = 125_000  # the second AD7171's nominal rate, as announced
FW_VERSION = (2, 1, 0)
LOCKOUT_FLOOR_US = 1000  # firmware config.h: DEBOUNCE_*_US_DEFAULT
LOCKOUT_CAP_US = 50_000  # LOCKOUT_CAP_US


#: Optiboot's wait for an upload after an external reset (~1 s on the Nano's new bootloader) + the sketch's setup
BOOTLOADER_S = 1.1
SUP_HELD_MAX = 2  # supervisor events held while the ring is full (firmware main.cpp SUP_HELD_MAX)

class EmulatedFirmware:
    """The Nano's behaviour on the bus.

    Parameters
    ----------
    protocol : "v2" (default), "v1" or "v0"
    ring_capacity : events the ring holds (the firmware's is 64)
    clock_offset_us : device counter value at boot; set near 2**32 to test the wrap
    clock_ppm : crystal error of the device's time base
    knows_caps : False emulates the firmware from before the input channel (CAPS, SET_CHANNELS unknown)
    input_fitted : a second AD7171 (the engine-side input torque) answers at boot: announced in the
        capabilities frame (v2 only), queued as tag 4 once the host enabled it in this boot
    supervisor : the run-enable output (D7, issue 37; v2 only): :class:`dyno.sim.supervisor.NanoSupervisor`,
        ``on_run_enable(on, t_s, cause)`` is told every change (the simulated rig's kill chain); False
        emulates the firmware before it (SET_SUPERVISOR an unknown op, no capability bit)
    """

    def __init__(self, protocol: str = "v2", ring_capacity: int = 64, clock_offset_us: int = 0,
                 clock_ppm: float = 0.0, input_fitted: bool = False, knows_caps: bool = True,
                 supervisor: bool = True, pace: float = 1.0, on_run_enable=None) -> None:
        self.protocol = protocol
        self.has_supervisor = bool(supervisor) and protocol == "v2" and knows_caps
        self.on_run_enable = on_run_enable  # f(on, t_s, cause): the wiring behind D7
        # pace: a simulation at N x real time keeps the heartbeat's real-time timeout (dyno.sim.supervisor)
        self.supervisor = NanoSupervisor(self._push_supervisor, self._run_enable_changed, pace=pace)
        self.knows_caps = knows_caps  # False: firmware from before the input channel (CAPS is an unknown op)
        self.input_fitted = bool(input_fitted) and protocol == "v2"
        self.ring_capacity = ring_capacity
        self.clock_offset_us = clock_offset_us
        self.clock_scale = 1.0 + clock_ppm * 1e-6
        self.boot_time_s = 0.0
        self.boot_count = 0
        # v2 boot identity: the firmware's .noinit counter, +1 on every boot (RAM survives
        # a reset; simavr and this model start it at 0, so the first boot is 1).
        self.boot_id = 1
        self.reset_cause = v2.CAUSE_PORF
        self.ack_from_old_boot = 0  # v2: ACK_POLLs naming another boot (ignored), for audits
        self.first_served_s: dict[int, float] = {}  # boot_id -> sim time its first frame went out
        self.run_enable_log: list[tuple[float, bool, str]] = []  # (sim t, D7 on, cause): the truth
        self.retired_log: list | None = None  # set to [] to record (boot_id, raw) of every retired frame
        # v1: fixed lock-outs (the thesis's 10 / 6 ms); v2: the floor of the adaptive lock-out
        self.debounce_us = ({v1.CH_PRIMARY: 10_000, v1.CH_SECONDARY: 6_000} if protocol == "v1"
                            else {v1.CH_PRIMARY: LOCKOUT_FLOOR_US, v1.CH_SECONDARY: LOCKOUT_FLOOR_US})
        self.served: dict[int, bytes] = {}  # seq -> bytes last served (truth for audits)
        self.served_v0: deque = deque(maxlen=512)  # v0: the frames last served (truth for audits)
        self.events_generated = 0  # accepted into the ring (truth)
        self.bounces_rejected = 0
        self._boot(0.0)

    # --- state ---------------------------------------------------------------
    def _boot(self, now_s: float) -> None:
        self.boot_time_s = now_s
        self.ring: deque = deque()
        self._sup_held: list[tuple] = []  # supervisor events waiting for room in the ring
        self.events_dropped = 0
        self.overflow = False
        self._gap = False
        self.seq = 0
        self.reset_flag = True
        self.frame: bytes | None = None
        self.frame_events: tuple = ()
        self.frame_sent = False
        self.info_pending = False
        self.caps_pending = False
        self.channels_enabled = 0  # SET_CHANNELS mask; RAM, so every boot starts with the input off
        self._caps_seq = 0  # the data seq when the capabilities frame was built
        self._last_edge_us: dict[int, int | None] = {v1.CH_PRIMARY: None, v1.CH_SECONDARY: None}
        self._last_edge_s: dict[int, float] = {v1.CH_PRIMARY: 0.0, v1.CH_SECONDARY: 0.0}
        self.lockout_rejected = {v1.CH_PRIMARY: 0, v1.CH_SECONDARY: 0}  # since boot, as on the device
        self._period_us: dict[int, int | None] = {v1.CH_PRIMARY: None, v1.CH_SECONDARY: None}
        self._legacy = {v1.CH_PRIMARY: [100, 0], v1.CH_SECONDARY: [100, 0], v1.CH_ADC: [0, 0]}
        self._legacy_prev_t = {v1.CH_PRIMARY: 0, v1.CH_SECONDARY: 0}

    def _lockout_us(self, tag: int) -> int:
        """v1: the fixed window; v2: a quarter of the last period within [floor, cap] (firmware capture.c;
        the simulated Hall pulses have no width, so it runs from the accepted edge)."""
        floor = self.debounce_us[tag]
        period = self._period_us[tag]
        if self.protocol != "v2" or period is None:
            return floor
        return max(floor, min(LOCKOUT_CAP_US, period >> 2))

    def reset(self, now_s: float, cause: int = v2.CAUSE_WDRF) -> None:
        """Watchdog (default) or other reset: counters and buffers restart, a new boot id.

        After an external reset (the RESET line: the Pi's transistor, or the USB chip's DTR when its port is
        opened) the bootloader listens for an upload :data:`BOOTLOADER_S` first: the sketch — its ISRs, its
        I2C slave, its serial answers — starts only then (:meth:`running`).  Optiboot skips that wait after a
        watchdog reset."""
        self.boot_count += 1
        self.boot_id = (self.boot_id + 1) & 0xFFFF
        self.reset_cause = cause & 0x0F
        self.supervisor.service(now_s)  # (an expiry before the reset happened first)
        self.supervisor.boot(now_s, cause="reset")  # the pins go high-Z at the reset: the pull-down holds D7 off
        self._boot(now_s + (BOOTLOADER_S if cause & v2.CAUSE_EXTRF else 0.0))

    def running(self, now_s: float) -> bool:
        """The sketch runs (not the bootloader after an external reset)."""
        return now_s >= self.boot_time_s

    def device_us(self, t_s: float) -> int:
        """The device's u32 microsecond counter at simulation time ``t_s``."""
        ticks = int((t_s - self.boot_time_s) * 1e6 * self.clock_scale)
        return (self.clock_offset_us + ticks) & 0xFFFFFFFF

    # --- capture (what the ISRs and the ADC loop do) ----------------------------
    def capture(self, channel: str, t_s: float, code: int = 0, status: int = 0) -> None:
        if t_s < self.boot_time_s:
            return  # the bootloader: no ISR runs yet
        tag = CHANNEL_TAG[channel]
        if tag == v2.CH_INPUT and not (self.input_fitted and self.channels_enabled & v2.CHANNEL_INPUT):
            return  # not fitted, or not enabled by this boot's host: its RDY is not serviced
        t_us = self.device_us(t_s)
        self.supervisor.service(t_s)
        period_from_s = None
        if tag not in v2.ADC_TAGS:
            last = self._last_edge_us[tag]
            if last is not None and ((t_us - last) & 0xFFFFFFFF) < self._lockout_us(tag):
                self.bounces_rejected += 1
                self.lockout_rejected[tag] = (self.lockout_rejected[tag] + 1) & 0xFFFF
                return
            if last is not None:
                self._period_us[tag] = (t_us - last) & 0xFFFFFFFF
                period_from_s = self._last_edge_s[tag]
            self._last_edge_us[tag] = t_us
            self._last_edge_s[tag] = t_s
            code = status = 0  # a Hall edge carries only its time
        if self.protocol == "v0":
            self._capture_v0(tag, t_us, code, status)
            return
        self._push(tag, t_us, code, status)
        if period_from_s is not None:  # the loop sees the period after the edge is queued
            self.supervisor.period(tag, period_from_s, t_s, self._period_us[tag])

    def _push_supervisor(self, tag: int, t_s: float, code: int, status: int) -> None:
        """Queued only once this boot's host armed it (an old host never sees tag 5); never dropped for lack
        of room: held (two at most, as the firmware's ``sup_held``) until the host retired some."""
        if not self.supervisor.armed:
            return
        self._flush_supervisor()
        if len(self._sup_held) == SUP_HELD_MAX:  # a third change while two wait: the oldest lost, counted
            self._sup_held.pop(0)
            self.events_dropped = (self.events_dropped + 1) & 0xFFFF
            self.overflow = True
            self._gap = True
        self._sup_held.append((tag, self.device_us(t_s), code, status))
        self._flush_supervisor()

    def _flush_supervisor(self) -> None:
        while self._sup_held and len(self.ring) < self.ring_capacity:
            self._push(*self._sup_held.pop(0))

    def _run_enable_changed(self, on: bool, t_s: float, cause: str) -> None:
        self.run_enable_log.append((t_s, on, cause))
        if self.on_run_enable is not None:
            self.on_run_enable(on, t_s, cause)

    @property
    def run_enable(self) -> bool:
        """D7's level now (the last decision; :meth:`service` first to take an expired heartbeat)."""
        return self.supervisor.on

    def service(self, now_s: float) -> None:
        """The firmware's main loop at ``now_s``: the supervisor's heartbeat check, its held events."""
        self.supervisor.service(now_s)
        self._flush_supervisor()

    def next_deadline_s(self) -> float | None:
        """When the output drops unless the host polls (the bus steps the physics to it exactly)."""
        return self.supervisor.deadline_s()

    def _push(self, tag: int, t_us: int, code: int, status: int) -> None:
        if len(self.ring) >= self.ring_capacity:
            self.events_dropped = (self.events_dropped + 1) & 0xFFFF
            self.overflow = True
            self._gap = self.protocol == "v2"  # v2 marks the next event that gets in
            return
        self.events_generated += 1
        self.ring.append(v1.Event(tag, t_us, code, status, self._gap))
        self._gap = False

    def _capture_v0(self, tag: int, t_us: int, code: int, status: int) -> None:
        self.events_generated += 1
        if tag == v1.CH_ADC:
            if not status & v1.ADC_STATUS_ERR:  # the thesis sketch drops errored reads
                self._legacy[tag] = [code, t_us]
            return
        period = (t_us - self._legacy_prev_t[tag]) & 0xFFFFFFFF
        self._legacy_prev_t[tag] = t_us
        rpm = min(65535, 60_000_000 // period) if period else 0
        self._legacy[tag] = [rpm, t_us]

    # --- the bus side --------------------------------------------------------------
    def write(self, data: bytes, now_s: float) -> None:
        """The master wrote ``data`` (a command)."""
        if self.protocol == "v0" or not data:
            return
        proto = v2 if self.protocol == "v2" else v1
        try:
            cmd = proto.decode_command(bytes(data))
        except FrameError:
            return  # ignored, as the firmware does: the current frame is served again
        if not self.knows_caps and cmd.op in (v2.OP_CAPS, v2.OP_SET_CHANNELS):
            return  # older firmware: an unknown op, ignored the same way
        if cmd.op in (v2.OP_SET_SUPERVISOR, v2.OP_PULSE_RUN_ENABLE) and not self.has_supervisor:
            return  # firmware before the run-enable: an unknown op
        if cmd.op == v2.OP_PULSE_RUN_ENABLE:
            (ms,) = cmd.args
            if 1 <= ms <= v2.PULSE_MS_MAX or ms == v2.PULSE_LATCH:  # (else ignored, as by the firmware; not a heartbeat either way)
                self.supervisor.pulse(now_s, ms)
            return
        if self.has_supervisor and cmd.op in (v1.OP_POLL, v1.OP_ACK_POLL, v2.OP_SET_SUPERVISOR):
            self.supervisor.heartbeat(now_s)
        if cmd.op == v2.OP_SET_SUPERVISOR:
            if self.supervisor.arm(now_s, *cmd.args):
                self._caps_seq = self.seq
            return
        if cmd.op == v1.OP_ACK_POLL:
            if self.protocol == "v2":
                boot, seq = cmd.args
                if boot != self.boot_id:
                    self.ack_from_old_boot += 1
                    return
            else:
                seq = cmd.args[0]
            if self.frame is not None and self.frame_sent and seq == self.seq:
                if self.retired_log is not None:
                    self.retired_log.append((self.boot_id, self.frame[: self.frame[1]]))
                self.frame = None
                self.frame_events = ()
                self.frame_sent = False
                self.seq = (self.seq + 1) & 0xFF
                self.reset_flag = False
        elif cmd.op == v1.OP_SET_DEBOUNCE:
            self.debounce_us[v1.CH_PRIMARY], self.debounce_us[v1.CH_SECONDARY] = cmd.args
        elif cmd.op == v1.OP_CLEAR_COUNTERS:
            self.events_dropped = 0
            self.overflow = False
        elif cmd.op == v1.OP_INFO:
            self.info_pending = True
        elif self.protocol == "v2" and cmd.op == v2.OP_CAPS:
            self.caps_pending = True
        elif self.protocol == "v2" and cmd.op == v2.OP_SET_CHANNELS:
            fitted = v2.CHANNEL_INPUT if self.input_fitted else 0
            self.channels_enabled = cmd.args[0] & fitted  # a channel not fitted stays off
            self._caps_seq = self.seq

    def read(self, n: int, now_s: float) -> bytes:
        """The master reads ``n`` bytes; returns what the device puts on the bus."""
        if self.protocol == "v0":
            (rp, tp), (rs, ts), (adc, ta) = (self._legacy[c] for c in (1, 2, 3))
            out = v0.encode_legacy_frame(v0.LegacyFrame(rp, tp, rs, ts, adc, ta))
            self.served_v0.append(out)  # truth for the corrupted-accepted audit
            return out[:n].ljust(n, b"\xff")
        if self.caps_pending and self.protocol == "v2":
            self.caps_pending = False
            fitted = v2.CHANNEL_INPUT if self.input_fitted else 0
            sup = v2.CHANNEL_SUPERVISOR if self.has_supervisor else 0
            enabled = self.channels_enabled | (sup if self.supervisor.armed else 0)
            # as the firmware builds it: at boot and after each SET_CHANNELS (its seq then), the flags
            # the reset cause only (as the info frame's)
            caps = v2.CapsFrame(self._caps_seq, self.reset_cause << v2.CAUSE_SHIFT, self.boot_id, fitted | sup,
                                enabled,
                                v2.CONVERTER_AD7171 if fitted else v2.CONVERTER_NONE,
                                INPUT_RATE_MHZ if fitted else 0)
            return v2.encode_caps_frame(caps)[:n].ljust(n, b"\xff")
        if self.info_pending and self.protocol == "v2":
            self.info_pending = False
            info2 = v2.InfoFrame(self.seq, self._flags(), self.boot_id, FW_VERSION,
                                 int((now_s - self.boot_time_s) * 1000) & 0xFFFFFFFF,
                                 self.debounce_us[v1.CH_PRIMARY], self.debounce_us[v1.CH_SECONDARY],
                                 (self.lockout_rejected[v1.CH_PRIMARY], self.lockout_rejected[v1.CH_SECONDARY]))
            return v2.encode_info_frame(info2)[:n].ljust(n, b"\xff")
        if self.info_pending:
            self.info_pending = False
            info = v1.InfoFrame(self.seq, self._flags(), FW_VERSION, self.boot_count,
                                int((now_s - self.boot_time_s) * 1000) & 0xFFFFFFFF,
                                self.debounce_us[v1.CH_PRIMARY], self.debounce_us[v1.CH_SECONDARY])
            return v1.encode_info_frame(info)[:n].ljust(n, b"\xff")
        if not self.frame_sent:
            self._build(now_s)
        self.frame_sent = True
        self.first_served_s.setdefault(self.boot_id, now_s)
        self.served[self.seq] = self.frame[: self.frame[1]]
        # A master reading past our buffer gets 0xFF (SDA released).
        return self.frame[:n].ljust(n, b"\xff")

    def _flags(self) -> int:
        f = v1.FLAG_RESET if self.reset_flag else 0
        if self.protocol == "v2":
            f |= self.reset_cause << v2.CAUSE_SHIFT
            if self.supervisor.on:
                f |= v2.FLAG_RUN
        return f | (v1.FLAG_OVERFLOW if self.overflow else 0)

    def _build(self, now_s: float) -> None:
        """(Re)build the unsent current frame from the ring (events stay queued until retired)."""
        # Put the current frame's events back first: an unsent frame may be rebuilt.
        if self.frame_events:
            self.ring.extendleft(reversed(self.frame_events))
        self._flush_supervisor()
        proto = v2 if self.protocol == "v2" else v1
        n = proto.fit_events(self.ring)
        events = tuple(self.ring.popleft() for _ in range(n))
        flags = self._flags() | (v1.FLAG_MORE if self.ring else 0)
        self.frame_events = events
        if proto is v2:
            self.frame = v2.encode_data_frame(self.seq, flags, self.boot_id, self.events_dropped, events,
                                              self.device_us(now_s))
        else:
            self.frame = v1.encode_data_frame(self.seq, flags, self.events_dropped, events, self.device_us(now_s))
