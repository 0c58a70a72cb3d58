import pytest
"""A long-lived poller forgets old events (the UI re-arms run after run on one poller) without changing
what any later window reads, and the safety monitor's ADC checks neither replay nor skip a sample."""

from types import SimpleNamespace

import numpy as np

from dyno.acquisition.streams import Streams
from dyno.control.safety import SafetyLimits, SafetyMonitor
from dyno.protocol import v1
from dyno.sim.rig import TruthRecorder

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def _events(t0_us, n, code=lambda k: 30000 + (k % 7), status=0):
    out = []
    for k in range(n):
        t = t0_us + 8000 * k
        out += [v1.Event(v1.CH_PRIMARY, t + 100), v1.Event(v1.CH_SECONDARY, t + 300),
                v1.Event(v1.CH_ADC, t + 500, code(k), status)]
    return out


def test_trim_keeps_every_window_after_the_cut():
    s = Streams()
    s.extend(_events(0, 1000))
    before = (s.edge_window(1, 4_000_000, 8_000_000), s.adc_window(4_000_000, 8_000_000)[1],
              s.edge_gap_window(2, 4_000_000, 8_000_000))
    dropped = s.trim_before(4_000_000)
    assert dropped == 3 * 500  # 500 of each channel are older than 4 s
    assert s.edges[1][0] >= 4_000_000 and s.adc_t[0] >= 4_000_000 and len(s.edge_rpm[1]) == len(s.edges[1])
    assert s.adc_total == 1000 and s.adc_trimmed == 500
    after = (s.edge_window(1, 4_000_000, 8_000_000), s.adc_window(4_000_000, 8_000_000)[1],
             s.edge_gap_window(2, 4_000_000, 8_000_000))
    for a, b in zip(before, after):
        assert np.array_equal(a, b)
    assert s.trim_before(4_000_000) == 0  # nothing more to drop


def test_safety_adc_checks_continue_across_a_trim():
    """Stuck codes straddling a trim still count as one run (no sample replayed, none skipped)."""
    streams = Streams()
    poller = SimpleNamespace(streams=streams)
    lim = SafetyLimits()
    mon = SafetyMonitor(lim, poller)
    streams.extend(_events(0, 200))
    mon._update_adc()
    assert mon._adc_same_run == 1
    half = lim.adc_stuck_run // 2
    streams.extend(_events(1_600_000, half, code=lambda k: 12345))
    mon._update_adc()
    streams.trim_before(1_600_000)  # all the varying codes gone; the stuck half stays
    streams.extend(_events(1_600_000 + 8000 * half, lim.adc_stuck_run - half, code=lambda k: 12345))
    mon._update_adc()
    assert mon._adc_same_run == lim.adc_stuck_run  # exactly: a replayed sample would make it more
    streams.trim_before(10**9)  # everything seen is dropped; new samples are still read once each
    streams.extend(_events(10**9, 3, code=lambda k: 777, status=v1.ADC_STATUS_ERR))
    mon._update_adc()
    assert mon._adc_err_run == 3


def test_truth_recorder_trim_keeps_later_windows():
    class Model:
        t = 0.0

        def truth(self):
            t = self.t
            return SimpleNamespace(t_s=t, power_in_w=1000.0 + t, power_out_w=900.0, rpm_primary=3000.0 + t,
                                   rpm_secondary=1500.0, torque_secondary_nm=20.0, rotor_temp_c=40.0,
                                   ratio_geometric=2.0, belt_slip=0.01)

    m = Model()
    rec = TruthRecorder(m)
    for k in range(1000):
        m.t = k * 0.01
        rec(None, m.t)
    before = rec.window(6.0, 8.0)
    assert rec.trim_before(5.0) == 500
    assert rec.t[0] >= 5.0 and all(len(getattr(rec, f)) == len(rec.t) for f in rec.FIELDS)
    assert rec.window(6.0, 8.0) == before
