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
        self.adc_t = array("q")
        self.adc_code = array("H")
        self.adc_status = array("B")
        self.out_of_order = 0

    def extend(self, events) -> None:
        for e in events:
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

    def last_edges(self, channel: int, n: int = 2):
        ts = self.edges[channel]
        return ts[-n:]

    def latest_time_us(self) -> int | None:
        cands = [a[-1] for a in (self.edges[1], self.edges[2], self.adc_t) if a]
        return max(cands) if cands else None

    def counts(self) -> dict:
        return {"primary_edges": len(self.edges[1]), "secondary_edges": len(self.edges[2]),
                "adc_samples": len(self.adc_t)}
