"""The live screen's values at part throttle: the efficiency's denominator is the engine-map curve at the
commanded throttle (``controller.throttle_frac``), never the full-throttle one; none -> n/a with a reason."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from dyno.analysis.engine_map import load_engine_map
from dyno.protocol import v1
from dyno.analysis.live import RAD_S_PER_RPM, RateMeter, live_values
from dyno.ui.live_model import efficiency_text

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

FULL_MAP = "calibration/engine_maps/baja-10hp-representative.csv"
PART_MAP = "calibration/engine_maps/baja-10hp-representative-part-throttle.csv"
COUNTS_PER_NM, OFFSET = 108.0, 35000.0


class _Streams:
    def __init__(self, torque_nm: float) -> None:
        self.code = int(round(OFFSET + COUNTS_PER_NM * torque_nm))

    def adc_window(self, t0_us, t1_us):
        n = 40  # ~0.3 s of conversions at 125 Hz
        return (np.linspace(t0_us, t1_us, n).astype(np.int64), np.full(n, self.code, dtype=np.int64),
                np.zeros(n, dtype=np.int64))


def _rig(engine_map, throttle_frac: float, *, rpm_primary=3000.0, rpm_secondary=2500.0, torque_nm=12.0):
    rpms = {v1.CH_PRIMARY: rpm_primary, v1.CH_SECONDARY: rpm_secondary}
    stats = SimpleNamespace(accepted=100, rejected={}, transport_errors={})
    poller = SimpleNamespace(rpm=rpms.__getitem__, streams=_Streams(torque_nm), device_now_us=lambda: 10_000_000,
                             reader=SimpleNamespace(stats=stats, events_lost=0), rotor_temp_c=80.0)
    cal = SimpleNamespace(torque_secondary_nm=lambda c: (c - OFFSET) / COUNTS_PER_NM)
    ctrl = SimpleNamespace(state=SimpleNamespace(value="measure"), reason="", paused=False, calibration=cal,
                           engine_map=engine_map, aborts=[], limits=SimpleNamespace(rotor_temp_max_c=300.0),
                           points=[], throttle_frac=throttle_frac)
    return poller, ctrl


def _values(engine_map, throttle_frac, **kw):
    poller, ctrl = _rig(engine_map, throttle_frac, **kw)
    return live_values(poller, ctrl, 1.0, RateMeter())


def test_live_efficiency_uses_the_curve_at_the_commanded_throttle():
    m = load_engine_map(PART_MAP)
    v = _values(m, 0.6)
    p_out = round(OFFSET + COUNTS_PER_NM * 12.0) - OFFSET
    p_out = p_out / COUNTS_PER_NM * 2500.0 * RAD_S_PER_RPM
    p_part = m.at_throttle(0.6).power_w(3000.0)
    assert v.power_out_w == pytest.approx(p_out)
    assert v.power_engine_w == pytest.approx(p_part)
    assert v.efficiency == pytest.approx(p_out / p_part)
    assert v.efficiency_reason is None
    # the part-throttle engine makes less than the full curve says: the full map would under-read efficiency
    assert p_part < 0.9 * m.power_w(3000.0)
    assert efficiency_text(v, loaded=True) == f"{100 * p_out / p_part:.1f} %"
    # at full throttle the full curve, as before
    full = _values(m, 1.0)
    assert full.efficiency == pytest.approx(p_out / m.power_w(3000.0)) and full.efficiency_reason is None


def test_live_efficiency_without_a_curve_at_the_throttle_is_na_with_a_reason():
    v = _values(load_engine_map(FULL_MAP), 0.6)  # a full-throttle-only map
    assert math.isnan(v.efficiency) and math.isnan(v.power_engine_w)
    assert not math.isnan(v.power_out_w)  # the measurement stays: only the denominator is missing
    assert v.efficiency_reason == "no 60 % curve"
    assert efficiency_text(v, loaded=True) == "n/a: no 60 % curve"  # 18 characters: fits the fields column
    v = _values(load_engine_map(PART_MAP), 0.55)  # between curves: no blend across throttle
    assert math.isnan(v.efficiency) and v.efficiency_reason == "no 55 % curve"


def test_live_efficiency_outside_the_map_and_while_not_loaded():
    v = _values(load_engine_map(PART_MAP), 1.0, rpm_primary=9000.0)
    assert math.isnan(v.efficiency) and efficiency_text(v, loaded=True) == "n/a: rpm off map"
    v = _values(load_engine_map(PART_MAP), 0.6, rpm_primary=3200.0)  # past the 0.6 curve's governor cut-off
    assert math.isnan(v.power_engine_w) and efficiency_text(v, loaded=True) == "n/a: rpm off map"
    v = _values(None, 1.0)
    assert math.isnan(v.efficiency) and efficiency_text(v, loaded=True) == "n/a: no engine map"
    ok = _values(load_engine_map(PART_MAP), 1.0)
    assert efficiency_text(ok, loaded=False) == "—"  # idle, ramps, coasting: no efficiency to read
    stopped = _values(load_engine_map(PART_MAP), 1.0, rpm_primary=math.nan)
    assert math.isnan(stopped.efficiency) and efficiency_text(stopped, loaded=True) == "—"
