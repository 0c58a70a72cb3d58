"""Host side of the v1 acknowledge/re-send exchange (pure: bytes in, decisions out).

Every poll acknowledges the last frame the host accepted.  The device retires a
frame only when the acknowledged sequence number is its current frame's *and*
that frame has been sent at least once; otherwise it serves the same frame
again.  So a corrupted, truncated or NACKed transfer is simply re-read: no event
is lost and none is counted twice.

A frame whose bytes equal the last accepted frame's is a *stale repeat* (our
acknowledgement was lost): rejected and counted, never re-delivered.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from dyno.errors import FrameError
from dyno.protocol import v1


@dataclass
class LinkStats:
    read: int = 0
    accepted: int = 0
    rejected: Counter = field(default_factory=Counter)
    device_resets: int = 0
    resyncs: int = 0
    transport_errors: Counter = field(default_factory=Counter)

    def as_dict(self) -> dict:
        return {
            "read": self.read,
            "accepted": self.accepted,
            "rejected": dict(sorted(self.rejected.items())),
            "rejected_total": sum(self.rejected.values()),
            "device_resets": self.device_resets,
            "resyncs": self.resyncs,
            "transport_errors": dict(sorted(self.transport_errors.items())),
        }


class LinkSession:
    """Decides what to write next and whether a read is a new, valid frame."""

    def __init__(self) -> None:
        self.stats = LinkStats()
        self.last_seq: int | None = None
        self.last_accepted: bytes | None = None  # raw bytes of the last accepted frame
        self.frame_listeners: list = []  # callables(raw) on every accepted frame
        self._suspect: bytes | None = None  # a CRC-valid frame out of sequence
        self.info: v1.InfoFrame | None = None

    def request(self) -> bytes:
        """The command to write before the next read."""
        return v1.poll(self.last_seq)

    def transport_error(self, cause: str) -> None:
        self.stats.read += 1
        self.stats.transport_errors[cause] += 1

    def accept(self, buf: bytes) -> v1.DataFrame | None:
        """Check one read; return the frame if it is new and valid, else ``None``."""
        self.stats.read += 1
        try:
            frame = v1.decode_frame(buf)
        except FrameError as exc:
            self.stats.rejected[exc.cause] += 1
            return None
        if isinstance(frame, v1.InfoFrame):
            self.info = frame
            return None
        length = buf[1]
        raw = bytes(buf[:length])
        if raw == self.last_accepted:
            self.stats.rejected["stale_repeat"] += 1
            return None
        expected = None if self.last_seq is None else (self.last_seq + 1) & 0xFF
        if frame.flags & v1.FLAG_RESET and frame.seq == 0:
            if self.last_seq is not None:
                self.stats.device_resets += 1
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
