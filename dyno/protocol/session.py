"""Host side of the acknowledge/re-send exchange, v1 and v2 (pure: bytes in, decisions out).

Every poll acknowledges the last frame the host accepted.  The device retires a
frame only when the acknowledgement names its current frame (v2: and its boot)
*and* that frame has been sent at least once; otherwise it serves the same frame
again.  So a corrupted, truncated or NACKed transfer is simply re-read: no event
is lost and none is counted twice.

A frame whose bytes equal the last accepted frame's is a *stale repeat* (our
acknowledgement was lost): rejected and counted, never re-delivered.

v2 frames carry a boot identity: a frame whose ``boot_id`` differs from the one
the host is following is a new boot, whatever its seq and whenever it comes, and
the host's acknowledgements name the boot, so one meant for an old boot never
retires a frame of the new one (docs/protocol.md, "Boots and resets").
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from dyno.errors import ConfigError, FrameError
from dyno.protocol import v0, v1, v2


class ProtocolMismatch(ConfigError):
    """The device speaks another protocol version than the host was set to."""

    def __init__(self, device: str, host: str) -> None:
        super().__init__("device", "protocol",
                         f"the device speaks protocol {device}, the host is set to {host} "
                         f"(--protocol or `protocol` in the rig file)")
        self.device_version = device
        self.host_version = host


def sniff_version(buf: bytes) -> str | None:
    """The protocol a read is a *valid* frame of (v2, v1 or v0), or None."""
    for name, mod in (("v2", v2), ("v1", v1)):
        try:
            mod.decode_frame(buf)
            return name
        except FrameError:
            pass
    try:
        # A v0 sketch answers 20 bytes; a longer read gets 0xFF after them (SDA released),
        # or zeros (simavr's TWI, which keeps shifting TWDR out).
        tail = set(buf[v0.FRAME_LEN:])
        if len(buf) >= v0.FRAME_LEN and (tail <= {0xFF} or tail <= {0x00}):
            v0.decode_legacy_frame(bytes(buf[: v0.FRAME_LEN]))
            return "v0"
    except FrameError:
        pass
    return None


@dataclass
class LinkStats:
    read: int = 0
    accepted: int = 0
    rejected: Counter = field(default_factory=Counter)
    device_resets: int = 0
    resyncs: int = 0
    transport_errors: Counter = field(default_factory=Counter)
    boots: list = field(default_factory=list)  # v2: [{boot_id, cause, cause_name}] in order seen

    def as_dict(self) -> dict:
        return {
            "read": self.read,
            "accepted": self.accepted,
            "rejected": dict(sorted(self.rejected.items())),
            "rejected_total": sum(self.rejected.values()),
            "device_resets": self.device_resets,
            "resyncs": self.resyncs,
            "transport_errors": dict(sorted(self.transport_errors.items())),
            "boots": list(self.boots),
        }


class LinkSession:
    """Decides what to write next and whether a read is a new, valid frame.

    ``version`` is 2 (default) or 1.  A read that is a valid frame of another
    version raises :class:`ProtocolMismatch` (one line naming both versions).
    """

    def __init__(self, version: int = 2) -> None:
        if version not in (1, 2):
            raise ValueError(f"LinkSession speaks v1 or v2, not v{version}")
        self.version = version
        self.proto = v2 if version == 2 else v1
        self.stats = LinkStats()
        self.last_seq: int | None = None
        self.boot_id: int | None = None  # v2: the boot whose frames we follow
        self.reset_cause: int | None = None  # v2: MCUSR nibble of that boot
        self.last_accepted: bytes | None = None  # raw bytes of the last accepted frame
        self.frame_listeners: list = []  # callables(raw) on every accepted frame
        self._suspect: bytes | None = None  # a CRC-valid frame out of sequence
        self.info = None
        self.caps = None  # v2: the last capabilities frame read (the input channel's announcement)
        self.new_boot = False  # the last accepted frame started a new boot (v2) / had RESET (v1)
        self._foreign: str | None = None  # another version seen on the last read

    def request(self) -> bytes:
        """The command to write before the next read."""
        if self.version == 1:
            return v1.poll(self.last_seq)
        return v2.poll(None if self.last_seq is None else (self.boot_id, self.last_seq))

    def transport_error(self, cause: str) -> None:
        self.stats.read += 1
        self.stats.transport_errors[cause] += 1

    def _check_mismatch(self, buf: bytes) -> None:
        # Twice in a row: a device of another version answers so on every read, while
        # corruption that happens to pass the other version's checks does not repeat.
        other = sniff_version(buf)
        if other is not None and other != f"v{self.version}":
            if other == self._foreign:
                raise ProtocolMismatch(other, f"v{self.version}")
            self._foreign = other
            return
        self._foreign = None

    def accept(self, buf: bytes):
        """Check one read; return the data frame if it is new and valid, else ``None``."""
        self.stats.read += 1
        try:
            frame = self.proto.decode_frame(buf)
        except FrameError as exc:
            if exc.cause in ("version", "length", "crc"):
                self._check_mismatch(buf)
            else:
                self._foreign = None
            self.stats.rejected[exc.cause] += 1
            return None
        self._foreign = None
        if isinstance(frame, (v1.InfoFrame, v2.InfoFrame)):
            self.info = frame
            return None
        if isinstance(frame, v2.CapsFrame):
            self.caps = frame
            return None
        length = buf[1]
        raw = bytes(buf[:length])
        if raw == self.last_accepted:
            self.stats.rejected["stale_repeat"] += 1
            return None
        self.new_boot = False
        if self.version == 2:
            if frame.boot_id != self.boot_id or (self.last_seq is not None and frame.reset_cause != self.reset_cause):
                # Any frame of another boot: its first unretired frame (the device cannot
                # retire one before we acknowledge it with its own boot id).
                if self.boot_id is not None:
                    self.stats.device_resets += 1
                self.stats.boots.append({"boot_id": frame.boot_id, "cause": frame.reset_cause,
                                         "cause_name": v2.cause_name(frame.reset_cause),
                                         "first_seq": frame.seq})
                self.boot_id = frame.boot_id
                self.reset_cause = frame.reset_cause
                self.new_boot = True
                self.last_seq = None
        expected = None if self.last_seq is None else (self.last_seq + 1) & 0xFF
        if self.version == 1 and frame.flags & v1.FLAG_RESET and frame.seq == 0:
            if self.last_seq is not None:
                self.stats.device_resets += 1
            self.new_boot = self.last_seq is not None
        elif expected is not None and frame.seq != expected:
            # Cannot happen by protocol; a CRC-valid frame out of sequence is
            # either corruption the CRC missed or a device we lost track of.
            # Corruption does not repeat byte for byte, so accept it only when
            # the very same bytes come twice.
            if raw != self._suspect:
                self._suspect = raw
                self.stats.rejected["sequence"] += 1
                return None
            self.stats.resyncs += 1
        self._suspect = None
        self.last_accepted = raw
        self.last_seq = frame.seq
        self.stats.accepted += 1
        for fn in self.frame_listeners:
            fn(raw)
        return frame
