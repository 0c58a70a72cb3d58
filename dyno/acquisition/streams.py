"""Per-channel, append-only event streams on the host timeline.

Compact ``array`` storage (8 bytes per time) so a 72-minute run stays small;
lookups by time use ``bisect`` on the monotonic per-channel times.
"""

from __future__ import annotations

from array import array
from bisect import bisect_left, bisect_right

import numpy as np

from dyno.protocol import v1


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
        self.out_of_order = 0

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

    def edge_gap_window(self, channel: int, t0_us: int, t1_us: int) -> np.ndarray:
        ts = self.edges[channel]
        i, j = bisect_left(ts, t0_us), bisect_right(ts, t1_us)
        return np.frombuffer(self.edge_gap[channel], dtype=np.int8)[i:j].astype(bool)

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
        return {"primary_edges": len(self.edges[1]), "secondary_edges": len(self.edges[2]),
                "adc_samples": len(self.adc_t)}
