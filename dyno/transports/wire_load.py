"""Every byte the busiest second of a run can put on the firmware's link, from the protocol's own frame sizes.

The busiest second the rig file allows is one at its over-speed limits (a Hall edge a revolution on each
shaft: ``limits.overspeed_*_rpm``), with the AD7171 converting at its fastest and, on a rig with
``[input_torque]``, the second converter too.  In it:

* **the polls and their MORE bursts**: at each tick the events queued since the last one are packed into
  frames as the device packs them (:func:`dyno.protocol.v2.fit_events`: 15 payload bytes, 3 a Hall edge, 6 a
  conversion); a tick reads as many frames as that takes (the device says MORE; at least one, at most the
  poller's ``max_burst``).  Each read is one poll (``ACK_POLL``'s bytes, then the frame: all 32 on I²C,
  its own length on USB serial);
* **the retries**: one poll that fails and is retried ``i2c.retries`` times (on serial, re-polled once);
* **the boot's commands**, once (a Nano reset can fall in any second): INFO, CAPS twice (the enable is
  confirmed by a second capabilities frame), SET_CHANNELS where the rig has the input channel, and
  SET_SUPERVISOR with the limits where the run-enable is armed (``limits.supervisor_timeout_s`` > 0).
  The supervisor's heartbeat is the polls themselves: a valid poll restarts it (docs/protocol.md);
* **the thermometer's reads** where it shares the firmware's I²C bus (:data:`THERMOMETER_HZ`).

:func:`busiest_second` returns the count by kind; :mod:`dyno.transports.budget` turns it into the planned share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from dyno.protocol import v0, v1, v2

#: the AD7171's output rate at its fastest: nominal 125 S/s from an internal clock measured at 126.6-127.0 Hz
#: on the thesis rig (dyno/sim/rig_signals.py)
ADC_MAX_HZ = 127.0
#: the MLX90614's read word: command byte written, 3 bytes read (2 data + PEC); the poller's rate of it
THERMOMETER_MSGS = ((False, 1), (True, 3))
THERMOMETER_HZ = 10.0
#: reads per tick while the device says MORE (dyno.acquisition.poller.Poller's default)
MAX_BURST = 8


def i2c_clocks(msgs) -> int:
    """SCL clocks of one combined transaction: ``msgs`` are ``(is_read, n_bytes)`` pairs."""
    return 1 + sum(1 + 9 * (1 + n) for _, n in msgs)


def serial_bytes(request_bytes: int, frame_bytes: int) -> int:
    """Bytes on the wire for one serial exchange: each packet COBS-encoded (+1) and delimited (+1); no answer
    (``frame_bytes`` 0): the request's packet only."""
    return (request_bytes + 2) + (frame_bytes + 2 if frame_bytes else 0)


@dataclass
class WireSecond:
    """One second's transfers by kind: ``transfers[kind] = [(request bytes, answer bytes), ...]``."""

    transfers: dict = field(default_factory=dict)
    backlog: int = 0  # events still queued after the second's last burst: the poll rate cannot drain them

    def add(self, kind: str, request: int, answer: int, times: int = 1) -> None:
        self.transfers.setdefault(kind, []).extend([(request, answer)] * times)

    def count(self, kind: str) -> int:
        return len(self.transfers.get(kind, ()))


def _proto(rig):
    return {"v2": v2, "v1": v1}.get(rig.protocol)


def poll_request_bytes(rig) -> int:
    """The poll as sent once a frame was accepted (ACK_POLL: v2 6 bytes, v1 4; v0: an empty write)."""
    proto = _proto(rig)
    return len(proto.poll((0, 0)) if proto is v2 else proto.encode_command(v1.OP_ACK_POLL, 0)) if proto else 0


def read_bytes(rig) -> int:
    """The fixed read of every I²C poll (the Nano's 32-byte Wire buffer; v0: its 20-byte frame)."""
    return v0.FRAME_LEN if _proto(rig) is None else v2.FRAME_MAX


def _event_times(rig) -> list:
    """(t_s, channel) of the events of the busiest second, in time order."""
    rates = [(v1.CH_PRIMARY, rig.limits.overspeed_primary_rpm / 60.0),
             (v1.CH_SECONDARY, rig.limits.overspeed_secondary_rpm / 60.0), (v1.CH_ADC, ADC_MAX_HZ)]
    if getattr(rig, "input_torque", None) is not None and _proto(rig) is v2:
        rates.append((v2.CH_INPUT, ADC_MAX_HZ))
    events = []
    for k, (channel, hz) in enumerate(rates):
        phase = (k + 1) / (len(rates) + 1)  # the channels out of step, as real shafts and converters are
        events += [((i + phase) / hz, channel) for i in range(int(hz))]
    return sorted(events)


def _frames(proto, batch) -> list:
    """(length, events) of each frame a batch of (t_s, channel) events takes, packed as the device packs them."""
    events = [v1.Event(channel, int(t * 1e6)) for t, channel in batch]
    header, crc = proto.HEADER_LEN, proto.CRC_LEN
    event_len = proto.EVENT_LEN if proto is v2 else v1.EVENT_LEN
    frames = []
    while events:
        n = proto.fit_events(events)
        frames.append((header + sum(event_len[e.channel] for e in events[:n]) + crc, n))
        events = events[n:]
    return frames or [(header + crc, 0)]  # an empty frame still answers the poll


def busiest_second(rig, poll_hz: float | None = None, max_burst: int = MAX_BURST) -> WireSecond:
    """The transfers of the busiest second the rig file allows at ``poll_hz`` (default: its own)."""
    hz = rig.poll_hz if poll_hz is None else poll_hz
    proto = _proto(rig)
    serial = rig.transport == "serial"
    req, read = poll_request_bytes(rig), read_bytes(rig)
    second = WireSecond()
    ticks = max(0, math.floor(hz))
    events = _event_times(rig) if proto is not None else []
    i, queued = 0, []
    for k in range(ticks):
        end_s = (k + 1) / hz
        while i < len(events) and events[i][0] < end_s:
            queued.append(events[i])
            i += 1
        frames = _frames(proto, queued)[:max_burst] if proto is not None else [(read, 0)]
        for j, (length, n) in enumerate(frames):
            second.add("more" if j else "poll", req, length if serial else read)
            queued = queued[n:]  # what a burst could not read waits for the next tick
    second.backlog = len(queued)  # events the second's bursts could not read (a rate too slow to drain them)
    if ticks:
        second.add("retry", req, v2.FRAME_MAX if serial else read, rig.i2c.retries if not serial else 1)
    if proto is not None:
        _boot_commands(rig, proto, second, serial)
    return second


def _boot_commands(rig, proto, second: WireSecond, serial: bool) -> None:
    def answer(frame_len: int) -> int:  # serial: the frame's own length; I²C: the fixed read
        return frame_len if serial else read_bytes(rig)

    second.add("boot", len(proto.encode_command(v1.OP_INFO)), answer(proto.INFO_LEN))
    if proto is not v2:
        return
    second.add("boot", len(v2.encode_command(v2.OP_CAPS)), answer(v2.CAPS_LEN), 2)
    if getattr(rig, "input_torque", None) is not None:
        second.add("boot", len(v2.encode_command(v2.OP_SET_CHANNELS, v2.CHANNEL_INPUT)), 0)
    if rig.limits.supervisor_timeout_s > 0:
        second.add("supervisor", len(v2.supervisor_command(rig.limits.overspeed_primary_rpm,
                                                          rig.limits.overspeed_secondary_rpm,
                                                          rig.limits.supervisor_timeout_s)), 0)


def transfer_s(rig, request: int, answer: int) -> float:
    """One transfer's time on the wire at the rig file's clock."""
    if rig.transport == "serial":
        return 10 * serial_bytes(request, answer) / rig.serial.baud
    msgs = [m for m in ((False, request), (True, answer)) if m[1]]
    return i2c_clocks(msgs) / rig.i2c.bus_speed_hz


def busy_by_kind(rig, poll_hz: float | None = None, second: WireSecond | None = None) -> dict:
    """Seconds on the wire in the busiest second, by kind (poll, more, retry, boot, supervisor, thermometer)."""
    second = second or busiest_second(rig, poll_hz)
    out = {kind: sum(transfer_s(rig, q, a) for q, a in xs) for kind, xs in second.transfers.items()}
    if rig.transport == "i2c":
        out["thermometer"] = THERMOMETER_HZ * i2c_clocks(THERMOMETER_MSGS) / rig.i2c.bus_speed_hz
    return out
