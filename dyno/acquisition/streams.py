"""Per-channel, append-only event streams on the host timeline.

Compact ``array`` storage (8 bytes per time) so a 72-minute run stays small;
lookups by time use ``bisect`` on the monotonic per-channel times.
"""

from __future__ import annotations

from array import array
from bisect import bisect_left, bisect_right

import numpy as np

from dyno.protocol import v1

CH_INPUT = 4  # dyno.protocol.v2.CH_INPUT (the acquisition layer reads v1 and v2 events alike)


class Streams:
    def __init__(self) -> None:
        self.edges = {v1.CH_PRIMARY: array("q"), v1.CH_SECONDARY: array("q")}
        self.edge_rpm = {v1.CH_PRIMARY: array("H"), v1.CH_SECONDARY: array("H")}  # v0 device rpm
        # 1 where the period ending at this edge spans lost events (v2 marks the first event
        # after a ring saturation; the lost ones may have been of any channel)
        self.edge_gap = {v1.CH_PRIMARY: array("b"), v1.CH_SECONDARY: array("b")}
        self._gap_pending = {v1.CH_PRIMARY: False, v1.CH_SECONDARY: False}
        self.adc_t = array("q")
        self.adc_code = array("H")
        self.adc_status = array("B")
        # the engine-side input torque converter (protocol v2 tag 4; empty on a rig without it)
        self.input_t = array("q")
        self.input_code = array("H")
        self.input_status = array("B")
        self.out_of_order = 0
        #: ADC samples dropped from the front by ``trim_before``: a reader that walks the samples by index
        #: (the safety monitor) counts in ``adc_trimmed + local index`` so a trim never replays or skips one
        self.adc_trimmed = 0
        self.input_trimmed = 0  # the same for the input torque converter

    @property
    def adc_total(self) -> int:
        """ADC samples appended since the stream began (trimmed ones included)."""
        return self.adc_trimmed + len(self.adc_t)

    @property
    def input_total(self) -> int:
        """Input torque conversions appended since the stream began (trimmed ones included)."""
        return self.input_trimmed + len(self.input_t)

    def trim_before(self, t_us: int) -> int:
        """Forget every event older than ``t_us`` (device time); returns how many were dropped.

        A long-lived poller (the UI's session re-arms run after run on one poller) would otherwise
        keep every event since start-up: ~10 bytes each at a few hundred events/s, tens of MB over a
        working day.  Each run's events are in its own log; only windows after ``t_us`` stay readable.
        """
        dropped = 0
        for ch, ts in self.edges.items():
            i = bisect_left(ts, t_us)
            if i:
                del ts[:i], self.edge_rpm[ch][:i], self.edge_gap[ch][:i]
                dropped += i
        i = bisect_left(self.adc_t, t_us)
        if i:
            del self.adc_t[:i], self.adc_code[:i], self.adc_status[:i]
            self.adc_trimmed += i
            dropped += i
        i = bisect_left(self.input_t, t_us)
        if i:
            del self.input_t[:i], self.input_code[:i], self.input_status[:i]
            self.input_trimmed += i
            dropped += i
        return dropped

    def extend(self, events) -> None:
        pending = self._gap_pending
        for e in events:
            if e.gap:
                pending[v1.CH_PRIMARY] = pending[v1.CH_SECONDARY] = True
            if e.channel == v1.CH_ADC:
                if self.adc_t and e.t_us <= self.adc_t[-1]:
                    self.out_of_order += 1
                    continue
                self.adc_t.append(e.t_us)
                self.adc_code.append(e.code)
                self.adc_status.append(e.status)
            elif e.channel == CH_INPUT:
                if self.input_t and e.t_us <= self.input_t[-1]:
                    self.out_of_order += 1
                    continue
                self.input_t.append(e.t_us)
                self.input_code.append(e.code)
                self.input_status.append(e.status)
            else:
                ts = self.edges[e.channel]
                if ts and e.t_us <= ts[-1]:
                    self.out_of_order += 1
                    continue
                ts.append(e.t_us)
                self.edge_rpm[e.channel].append(min(e.code, 0xFFFF))
                self.edge_gap[e.channel].append(1 if pending[e.channel] else 0)
                pending[e.channel] = False

    def mark_gap(self) -> None:
        """Events were lost here (e.g. a device reset): no period may span this point."""
        self._gap_pending[v1.CH_PRIMARY] = self._gap_pending[v1.CH_SECONDARY] = True

    def edge_window(self, channel: int, t0_us: int, t1_us: int) -> np.ndarray:
        ts = self.edges[channel]
        i, j = bisect_left(ts, t0_us), bisect_right(ts, t1_us)
        return np.frombuffer(ts, dtype=np.int64)[i:j].copy()

    def edge_rpm_window(self, channel: int, t0_us: int, t1_us: int) -> np.ndarray:
        ts = self.edges[channel]
        i, j = bisect_left(ts, t0_us), bisect_right(ts, t1_us)
        return np.frombuffer(self.edge_rpm[channel], dtype=np.uint16)[i:j].astype(float)

    def adc_window(self, t0_us: int, t1_us: int):
        i, j = bisect_left(self.adc_t, t0_us), bisect_right(self.adc_t, t1_us)
        return (np.frombuffer(self.adc_t, dtype=np.int64)[i:j].copy(),
                np.frombuffer(self.adc_code, dtype=np.uint16)[i:j].astype(float),
                np.frombuffer(self.adc_status, dtype=np.uint8)[i:j].copy())

    def input_window(self, t0_us: int, t1_us: int):
        """The input torque converter's conversions in ``[t0_us, t1_us]``: times, codes, status."""
        i, j = bisect_left(self.input_t, t0_us), bisect_right(self.input_t, t1_us)
        return (np.frombuffer(self.input_t, dtype=np.int64)[i:j].copy(),
                np.frombuffer(self.input_code, dtype=np.uint16)[i:j].astype(float),
                np.frombuffer(self.input_status, dtype=np.uint8)[i:j].copy())

    def edge_gap_window(self, channel: int, t0_us: int, t1_us: int) -> np.ndarray:
        ts = self.edges[channel]
        i, j = bisect_left(ts, t0_us), bisect_right(ts, t1_us)
        return np.frombuffer(self.edge_gap[channel], dtype=np.int8)[i:j].astype(bool)

    def last_edge_us(self, channel: int) -> int | None:
        """The channel's newest edge time (µs), None before its first."""
        ts = self.edges[channel]
        return ts[-1] if ts else None

    def last_edges(self, channel: int, n: int = 2):
        ts = self.edges[channel]
        return ts[-n:]

    def last_valid_pair(self, channel: int, search: int = 8):
        """The latest two adjacent edges with no loss between them (None if none of the last few)."""
        ts, gaps = self.edges[channel], self.edge_gap[channel]
        for k in range(len(ts) - 1, max(0, len(ts) - search), -1):
            if not gaps[k]:
                return ts[k - 1], ts[k]
        return None

    def latest_time_us(self) -> int | None:
        cands = [a[-1] for a in (self.edges[1], self.edges[2], self.adc_t) if a]
        return max(cands) if cands else None

    def counts(self) -> dict:
        out = {"primary_edges": len(self.edges[1]), "secondary_edges": len(self.edges[2]),
               "adc_samples": len(self.adc_t)}
        if self.input_t:
            out["input_samples"] = len(self.input_t)
        return out
