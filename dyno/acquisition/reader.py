"""Frame readers: one poll of a transport -> host-side events with unwrapped times.

A reader owns the protocol session for one device and turns accepted frames
into :class:`dyno.protocol.v1.Event` objects whose ``t_us`` is *unwrapped*
(monotonic int, not reduced mod 2**32) on one host timeline.  Readers are
synchronous and pure apart from the injected transport; the asyncio poller
schedules them.
"""

from __future__ import annotations

from dyno.errors import FrameError
from dyno.protocol import v0, v1, v2
from dyno.protocol.session import LinkSession, LinkStats, ProtocolMismatch, sniff_version
from dyno.transports.base import Transport, TransportFault

Event = v1.Event
REARM_EVERY_POLLS = 5  # an operator's re-arm re-sends SET_SUPERVISOR this often until a frame shows RUN
WRAP = 1 << 32
# data frames in answer to CAPS before the host takes the firmware for one without it: a corrupted CAPS
# gives one, and the firmware answers none while its boot probes for the converter (20 ms: 3 polls)
CAPS_TRIES = 8


class Unwrapper:
    """Unwraps u32 microsecond counters into one monotonic timeline.

    ``d = (t - r) mod 2**32`` read as signed 32-bit, added to the last
    unwrapped value: exact while consecutive times are < 2**31 us apart.
    """

    def __init__(self) -> None:
        self.raw: int | None = None
        self.unwrapped = 0
        self.offset = 0

    def __call__(self, t_raw: int) -> int:
        if self.raw is None:
            self.raw = t_raw
            self.unwrapped = self.offset + t_raw
            return self.unwrapped
        d = (t_raw - self.raw) & 0xFFFFFFFF
        if d & 0x80000000:
            d -= WRAP
        self.raw = t_raw
        self.unwrapped += d
        return self.unwrapped

    def new_epoch(self, gap_us: int) -> None:
        """The device restarted its counter: continue after a host-measured gap."""
        base = self.unwrapped + max(0, gap_us)
        self.raw = None
        self.offset = base

    def peek(self, t_raw: int) -> int:
        if self.raw is None:
            return self.offset + t_raw
        d = (t_raw - self.raw) & 0xFFFFFFFF
        return self.unwrapped + (d - WRAP if d & 0x80000000 else d)


class V1Reader:
    """Reads our firmware's framed protocol (v2 by default, or v1) with acknowledge/re-send."""

    read_len = v1.FRAME_MAX

    def __init__(self, transport: Transport, version: int = 2, *, want_input: bool = False,
                 supervisor_command: bytes | None = None) -> None:
        self.transport = transport
        self.version = version
        self.protocol = f"v{version}"
        self.proto = v2 if version == 2 else v1
        self.session = LinkSession(version)
        self.unwrap = Unwrapper()
        self.events_lost = 0
        self.device_time_us: int | None = None  # latest unwrapped device time known
        self.more = False
        self._dropped_last: int | None = None
        self._last_frame_s: float | None = None
        # The engine-side input torque channel (v2 extension): asked for only when the rig file declares
        # it; enabled in every boot whose capabilities announce it (RAM: a reset disables it again).
        self.want_input = want_input
        self.input_present: bool | None = None  # None: not asked yet in this boot
        self._caps_pending = False
        self._caps_data_answers = 0
        # The Nano's run-enable (issue 37): SET_SUPERVISOR with the rig file's limits, sent to the first boot whose
        # capabilities announce it until the device confirms it armed (None: never arm it); once armed, a later
        # boot is armed only by the operator's re-arm (rearm_supervisor).
        self.supervisor_command: bytes | None = supervisor_command
        self.supervisor_present: bool | None = None  # None: not asked yet
        self.supervisor_armed = False          # this boot confirmed it
        self.supervisor_ever_armed = False
        self.run_enable: bool | None = None    # the RUN flag of the last data frame (None: not armed yet)
        self.run_enable_drops: list[dict] = []  # {"cause", "t_us" (device time), "code"} in order
        self.supervisor_events: list[dict] = []  # every tag-5 event: {"t_us", "cause", "code"}
        self._gap_carry = False  # a stripped tag-5 event's GAP mark, for the next event kept
        self.supervisor_sent: list = []  # the boot id each SET_SUPERVISOR was written to, in order
        self._sup_rearm_polls: int | None = None  # an operator's re-arm waiting for RUN: polls since
        self._pulse_ms: int | None = None  # a kill-path probe's PULSE_RUN_ENABLE, written at the next poll
        self.pulses_sent: list[int] = []  # the ms of each PULSE_RUN_ENABLE written, in order

    @property
    def stats(self) -> LinkStats:
        return self.session.stats

    def _negotiate_input(self) -> None:
        """CAPS, then SET_CHANNELS(input) if the device announced the converter.

        Old firmware ignores CAPS (unknown op) and serves its current data frame, which is not
        acknowledged here, so the next poll reads it again: nothing is lost, the channel is absent.
        """
        try:
            buf = self.transport.transfer(v2.encode_command(v2.OP_CAPS), self.read_len)
        except TransportFault:
            # tried again at the next poll; no answer at all is what a firmware that does not know CAPS gives
            # over USB serial (it answers only the ops it knows): absent after CAPS_TRIES of them too
            self._caps_no_answer()
            return
        try:
            frame = v2.decode_frame(buf)
        except FrameError:
            return
        if not isinstance(frame, v2.CapsFrame) or frame.boot_id != self.session.boot_id:
            if isinstance(frame, v2.DataFrame):
                # Old firmware ignores CAPS and serves its data frame; so does new firmware whose
                # command the bus corrupted: absent only after CAPS_TRIES such answers in a row.
                self._caps_no_answer()
            return  # otherwise asked again at the next poll
        self._caps_data_answers = 0
        self.session.caps = frame
        if self.want_input:
            self.input_present = frame.has_input
        self.supervisor_present = frame.has_supervisor
        self.supervisor_armed = bool(frame.enabled & v2.CHANNEL_SUPERVISOR)
        self.supervisor_ever_armed |= self.supervisor_armed
        # pending until the device's own capabilities frame confirms the enable (a write can be lost)
        need_input = self.want_input and frame.has_input and not frame.enabled & v2.CHANNEL_INPUT
        # the first boot that announces it is armed by itself; after a reset of a boot that was armed, a new boot
        # stays cut until the operator re-arms (rearm_supervisor: issue 49, a Nano reset stays a cut)
        need_sup = (self.supervisor_command is not None and frame.has_supervisor and not self.supervisor_armed
                    and not self.supervisor_ever_armed)
        self._caps_pending = need_input or need_sup
        try:
            if need_input:
                self.transport.write(v2.encode_command(v2.OP_SET_CHANNELS, v2.CHANNEL_INPUT))
            if need_sup:
                self.transport.write(self.supervisor_command)
                self.supervisor_sent.append(self.session.boot_id)
        except TransportFault:
            pass

    def _caps_no_answer(self) -> None:
        self._caps_data_answers += 1
        if self._caps_data_answers >= CAPS_TRIES:
            if self.want_input:
                self.input_present = False
            self.supervisor_present = False
            self._caps_pending = False

    def rearm_supervisor(self) -> None:
        """Send the limits again (the operator's re-arm after a drop: the device latches it off until then),
        every few polls until a data frame shows RUN."""
        if self.supervisor_command is not None and self.version == 2 and self.supervisor_present:
            self._sup_rearm_polls = 0

    def can_pulse_run_enable(self) -> bool:
        """The Nano's run-enable exists and is armed in this boot: a pulse can probe it (issue 49)."""
        return self.supervisor_command is not None and self.version == 2 and bool(self.supervisor_present) \
            and self.supervisor_armed

    def pulse_run_enable(self, ms: int) -> None:
        """Ask the Nano to drop its run-enable for ``ms`` and turn it back on (written by the next poll, on the
        thread that polls: the transport is never written from two threads)."""
        self._pulse_ms = int(ms)

    def cut_run_enable(self) -> None:
        """Ask the Nano to drop its run-enable and keep it off until the operator's re-arm (PULSE_LATCH): the
        host's cut when its own kill path failed the probe."""
        self._pulse_ms = v2.PULSE_LATCH

    @property
    def commands_pending(self) -> bool:
        """A PULSE_RUN_ENABLE asked for and not yet written (it goes with the next poll)."""
        return self._pulse_ms is not None

    def _pulse_step(self) -> None:
        ms, self._pulse_ms = self._pulse_ms, None
        try:
            self.transport.write(v2.pulse_command(ms))
            self.pulses_sent.append(ms)
        except TransportFault:
            pass

    def _rearm_step(self) -> None:
        if self.run_enable:
            self._sup_rearm_polls = None
            return
        if self._sup_rearm_polls % REARM_EVERY_POLLS == 0:
            try:
                self.transport.write(self.supervisor_command)
                self.supervisor_sent.append(self.session.boot_id)
            except TransportFault:
                pass
        self._sup_rearm_polls += 1

    def _note_supervisor(self, frame, new_boot: bool, events: list) -> list:
        """Take the run-enable's state (RUN flag) and its tag-5 events out of a data frame."""
        if new_boot and self.supervisor_ever_armed:
            self.run_enable_drops.append({"cause": f"reset ({v2.cause_name(frame.reset_cause)})",
                                          "t_us": events[0].t_us if events else self.device_time_us, "code": 0})
            self.supervisor_armed = False
        sup = [e for e in events if e.channel == v2.CH_SUPERVISOR]
        for e in sup:
            cause = v2.SUP_CAUSE_NAMES.get(e.status, f"cause {e.status}")
            self.supervisor_events.append({"t_us": e.t_us, "cause": cause, "code": e.code, "status": e.status,
                                           "boot_id": self.session.boot_id})
            if e.status not in (v2.SUP_ON, v2.SUP_PULSE):  # (a pulse is the host's own probe, not a drop)
                self.run_enable_drops.append({"cause": cause, "t_us": e.t_us, "code": e.code})
        if self.supervisor_ever_armed:
            self.run_enable = bool(frame.flags & v2.FLAG_RUN)
        if not sup and not self._gap_carry:
            return events
        # A tag-5 event that entered the ring first after a saturation carries GAP for every channel: the mark
        # moves to the next event kept, so no Hall period is ever taken across the hole.
        kept = []
        for e in events:
            if e.channel == v2.CH_SUPERVISOR:
                self._gap_carry |= e.gap
                continue
            if self._gap_carry and not e.gap:
                e = Event(e.channel, e.t_us, e.code, e.status, True)
            self._gap_carry = False
            kept.append(e)
        return kept

    def poll(self, now_s: float) -> list[Event]:
        """One transaction; returns the new events (possibly none)."""
        try:
            buf = self.transport.transfer(self.session.request(), self.read_len)
        except TransportFault as exc:
            self.session.transport_error(exc.cause)
            self.more = False
            return []
        frame = self.session.accept(buf)
        if frame is None:
            self.more = False
            return []
        new_boot = self.session.new_boot if self.version == 2 else frame.flags & v1.FLAG_RESET
        if self.version == 2 and self.session.new_boot and (self.want_input or self.supervisor_command):
            self._caps_pending = True
            self._caps_data_answers = 0
            if self.want_input:
                self.input_present = None
        if new_boot and self._last_frame_s is not None:
            self.unwrap.new_epoch(int((now_s - self._last_frame_s) * 1e6))
            self._dropped_last = None
        self._last_frame_s = now_s
        if self._dropped_last is not None:
            self.events_lost += (frame.events_dropped - self._dropped_last) & 0xFFFF
        else:  # first frame, or after a reset / CLEAR_COUNTERS: the counter started at 0
            self.events_lost += frame.events_dropped
        self._dropped_last = frame.events_dropped
        self.more = bool(frame.flags & v1.FLAG_MORE)
        unwrap = self.unwrap
        out = [Event(e.channel, unwrap(e.t_us), e.code, e.status, e.gap) for e in frame.events]
        t_dev = unwrap.peek(frame.t0_us) if not out else max(e.t_us for e in out)
        if self.device_time_us is None or t_dev > self.device_time_us:
            self.device_time_us = t_dev
        if self.version == 2:
            out = self._note_supervisor(frame, bool(new_boot), out)
        if self._caps_pending:
            self._negotiate_input()
        elif self._sup_rearm_polls is not None:
            self._rearm_step()
        if self._pulse_ms is not None:
            self._pulse_step()
        return out

    @property
    def boot_id(self) -> int | None:
        """v2: the boot identity of the device's current boot (None before the first frame)."""
        return self.session.boot_id

    @property
    def reset_cause(self) -> int | None:
        """v2: the device's reset cause (MCUSR bits PORF, EXTRF, BORF, WDRF) for this boot."""
        return self.session.reset_cause

    def command(self, request: bytes) -> None:
        """Send a command that gets no answer (SET_DEBOUNCE, CLEAR_COUNTERS)."""
        self.transport.write(request)
        if request[:1] == bytes([v1.OP_CLEAR_COUNTERS]):
            self._dropped_last = None  # the device's counter restarts at 0: no jump in events_lost

    def clear_counters(self) -> None:
        self.command(self.proto.encode_command(v1.OP_CLEAR_COUNTERS))

    def read_info(self):
        """One INFO exchange: the info frame (v1 or v2 class), or None if the read failed."""
        try:
            buf = self.transport.transfer(self.proto.encode_command(v1.OP_INFO), self.read_len)
        except TransportFault:
            return None
        try:
            frame = self.proto.decode_frame(buf)
        except FrameError:
            return None
        return frame if isinstance(frame, self.proto.InfoFrame) else None


class V0Reader:
    """Reads the thesis rig's legacy 20-byte frame; new timestamps become events.

    Hall events carry the device's rpm value in ``code`` (v0 can miss edges
    between polls, so the rpm slot is the only trustworthy period then).
    """

    protocol = "v0"
    read_len = v0.FRAME_LEN

    def __init__(self, transport: Transport) -> None:
        self.transport = transport
        self.session = LinkSession()  # only its stats are used
        self.unwrap = Unwrapper()
        self.events_lost = 0  # unknowable in v0; reported as 0
        self.device_time_us: int | None = None
        self.more = False
        self._last_bytes: bytes | None = None
        self._last: v0.LegacyFrame | None = None
        self._last_now_s = 0.0
        self._pending = None  # (frame, raw, reason, now_s): implausible, awaiting its neighbour
        self._foreign: str | None = None  # a valid frame of another version on the last read

    @property
    def stats(self) -> LinkStats:
        return self.session.stats

    def poll(self, now_s: float) -> list[Event]:
        st = self.session.stats
        try:
            buf = self.transport.transfer(b"", self.read_len)
        except TransportFault as exc:
            self.session.transport_error(exc.cause)
            return []
        st.read += 1
        try:
            f = v0.decode_legacy_frame(buf)
        except FrameError as exc:
            other = sniff_version(buf) if exc.cause == "checksum" else None
            if other not in (None, "v0") and other == self._foreign:  # twice in a row: not noise
                raise ProtocolMismatch(other, "v0") from None
            self._foreign = other
            st.rejected[exc.cause] += 1
            return []
        self._foreign = None
        raw = bytes(buf[: v0.FRAME_LEN])
        if raw == self._last_bytes:
            st.rejected["stale_repeat"] += 1
            return []
        self._last_bytes = raw
        last = self._last
        if last is not None:
            why = implausible_v0(f, last, now_s - self._last_now_s)
            if why is not None:
                # A 16-bit sum lets some corrupted frames through.  Hold the odd one: if the
                # next frame agrees with it, the change was real (accept it late); if not,
                # it was corruption and is dropped.
                pending, self._pending = self._pending, (f, raw, why, now_s)
                if pending is None or implausible_v0(f, pending[0], now_s - pending[3]) is not None:
                    if pending is not None:
                        st.rejected[pending[2]] += 1
                    return []
                self._pending = None
                out = self._accept(pending[0], pending[1], last, pending[3])
                return out + self._accept(f, raw, pending[0], now_s)
            if self._pending is not None:
                st.rejected[self._pending[2]] += 1  # the odd frame stood alone: corruption
                self._pending = None
        return self._accept(f, raw, last, now_s)

    def _accept(self, f: v0.LegacyFrame, raw: bytes, last, now_s: float | None = None) -> list[Event]:
        st = self.session.stats
        st.accepted += 1
        for fn in self.session.frame_listeners:
            fn(raw)
        if now_s is not None:
            self._last_now_s = now_s
        self._last = f
        new = []
        if last is None or f.t_primary_us != last.t_primary_us:
            new.append(Event(v1.CH_PRIMARY, f.t_primary_us, f.rpm_primary))
        if last is None or f.t_secondary_us != last.t_secondary_us:
            new.append(Event(v1.CH_SECONDARY, f.t_secondary_us, f.rpm_secondary))
        if last is None or f.t_adc_us != last.t_adc_us:
            new.append(Event(v1.CH_ADC, f.t_adc_us, f.adc_code))
        if last is None:
            # The first read's slots hold whatever happened before we looked
            # (or the sketch's initial values): a time origin, not events.
            for e in sorted(new, key=lambda e: e.t_us):
                self.unwrap(e.t_us)
            return []
        new.sort(key=lambda e: (e.t_us - (last.t_adc_us)) & 0xFFFFFFFF)
        out = [Event(e.channel, self.unwrap(e.t_us), e.code, e.status) for e in new]
        self.device_time_us = max(e.t_us for e in out) if out else self.device_time_us
        return out


# v0 plausibility (the checksum is a 16-bit sum): what a frame may change since the last one
V0_TIME_MARGIN_US = 50_000  # clock slack between a Hall edge slot and the ADC slot
V0_RPM_JUMP_ABS = 400  # rpm: beyond this and ...
V0_RPM_JUMP_REL = 0.25  # ... this fraction of the last value, a one-poll change is suspect
# Torque code between two conversions 8 ms apart: the firing ripple moves it by up to ~2,000
# counts peak to peak (dyno/sim/rig_signals.py, from the thesis logs); a flipped bit 12+ moves it more.
V0_ADC_JUMP_COUNTS = 4000


def implausible_v0(f: v0.LegacyFrame, last: v0.LegacyFrame, host_dt_s: float) -> str | None:
    """Why frame ``f`` cannot follow ``last`` physically (a rejection cause), or None.

    * the ADC converts every 8 ms, so its slot's time advances by about the host's
      time between the reads (never backwards, never far more);
    * a value changes only with its timestamp (the sketch writes both together);
    * a new Hall edge time lies between the previous ADC time and the new one;
    * an rpm cannot jump by more than max(400 rpm, 25 %) within one poll;
    * the gap between the Hall edge times is a whole number of the periods the rpm slot
      states (a corrupted time would make it shorter, i.e. a false over-speed);
    * the torque code cannot move more than 4,000 counts between two conversions.
    """
    wrap = 0xFFFFFFFF
    d_adc = (f.t_adc_us - last.t_adc_us) & wrap
    if d_adc > max(0.0, host_dt_s) * 1e6 * 1.5 + V0_TIME_MARGIN_US:
        return "implausible_time"
    for rpm, t, rpm0, t0 in ((f.rpm_primary, f.t_primary_us, last.rpm_primary, last.t_primary_us),
                             (f.rpm_secondary, f.t_secondary_us, last.rpm_secondary, last.t_secondary_us)):
        if t == t0:
            if rpm != rpm0:
                return "implausible_value"
            continue
        since = (t - last.t_adc_us + V0_TIME_MARGIN_US) & wrap
        if since > d_adc + 2 * V0_TIME_MARGIN_US:
            return "implausible_time"
        if abs(rpm - rpm0) > max(V0_RPM_JUMP_ABS, V0_RPM_JUMP_REL * rpm0):
            return "implausible_rpm"
        if rpm > 0:
            # the slot's rpm is the device's own last period: the gap between the edge times
            # the host saw is a whole number of such periods (edges missed between polls)
            k = ((t - t0) & wrap) * rpm / 60e6
            if k < 0.8 or (k <= 6 and abs(k - round(k)) > 0.2):
                return "implausible_period"
    if f.t_adc_us == last.t_adc_us and f.adc_code != last.adc_code:
        return "implausible_value"
    if f.t_adc_us != last.t_adc_us and abs(f.adc_code - last.adc_code) > V0_ADC_JUMP_COUNTS:
        return "implausible_adc"
    return None


def run_enable_text(reader) -> str:
    """The Nano's run-enable in a few words for a face (live screen, web view, report): ``on``, ``off: CAUSE``
    (the last drop's), ``not armed`` (its limits not confirmed in this boot), ``absent`` (firmware without it)
    or ``n/a`` (not armed by this host, or not v2)."""
    if getattr(reader, "supervisor_command", None) is None:
        return "n/a"
    if reader.supervisor_present is False:
        return "absent"
    if reader.run_enable:
        return "on"
    if reader.run_enable_drops:
        return f"off: {reader.run_enable_drops[-1]['cause']}"
    return "off" if reader.run_enable is False else "not armed"


def make_reader(protocol: str, transport: Transport, *, supervisor_command: bytes | None = None,
                want_input: bool = False):
    """The reader for ``protocol``; v2 arms the Nano's run-enable with ``supervisor_command`` in every boot
    (``dyno.protocol.v2.supervisor_command``; None: never armed) and, with ``want_input``, enables the
    engine-side input torque converter in every boot that announces it (v1 and v0 have none)."""
    if protocol == "v2":
        return V1Reader(transport, 2, want_input=want_input, supervisor_command=supervisor_command)
    if protocol == "v1":
        return V1Reader(transport, 1)
    if protocol == "v0":
        return V0Reader(transport)
    raise ValueError(f"protocol must be v2, v1 or v0, not {protocol!r}")
