"""The simulated rig is its own engine, sensor and day (dyno.sim.world): drawn per seed with the spread
its parameters state, never the host's files; the ideal world is the host's knowledge exactly."""

from __future__ import annotations

import statistics

import numpy as np
import pytest

from dyno.analysis.calibration import load_history
from dyno.analysis.systematic import calibration_rel_u
from dyno.session.root import DEFAULT_CALIBRATION
from dyno.sim.engine import EngineMap
from dyno.sim.rig_params import RigParams
from dyno.sim.world import realise

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

MAP = EngineMap.from_csv("calibration/engine_maps/baja-10hp-representative.csv")


def _world(seed, **kw):
    return realise(RigParams(**kw), seed, MAP.rpm, MAP.torque_nm)


def test_draws_have_the_stated_spread():
    ws = [_world(s)[3] for s in range(400)]
    for rpm in (1800.0, 2600.0, 3400.0):
        sd = statistics.pstdev(w.engine_dev_rel_at(rpm) for w in ws)
        assert 0.043 < sd < 0.057  # 0.05 +- 3 standard errors of an sd from 400 draws
    gains = [w.adc_gain_drift_rel for w in ws]
    assert 0.0135 < statistics.pstdev(gains) < 0.018
    days = [(w.temp_c, w.pressure_kpa, w.rh_pct) for w in ws]
    assert min(d[0] for d in days) >= 5.0 and max(d[0] for d in days) <= 35.0
    assert 80.0 < min(d[1] for d in days) and max(d[1] for d in days) < 105.0


def test_gain_drift_default_is_the_calibration_history_reproducibility():
    history = load_history(DEFAULT_CALIBRATION)
    assert RigParams().adc_gain_drift_rel_sd == pytest.approx(calibration_rel_u(history, history[-1]), rel=0.02)


def test_true_engine_is_the_map_times_deviation_over_the_day():
    p, rpm, torque, w = _world(7)
    for i, n in enumerate(rpm):
        assert torque[i] == pytest.approx(MAP.torque_nm[i] * (1 + w.engine_dev_rel_at(n)) / w.j1349_factor)
    assert p.adc_gain_counts_per_nm == pytest.approx(RigParams().adc_gain_counts_per_nm * (1 + w.adc_gain_drift_rel))
    assert p.ambient_temp_c == w.temp_c


def test_ideal_world_is_the_host_knowledge():
    p, rpm, torque, w = _world(7, ideal=True)
    assert np.array_equal(torque, MAP.torque_nm) and w.j1349_factor == pytest.approx(1.0, abs=1e-12)
    assert p.adc_gain_counts_per_nm == RigParams().adc_gain_counts_per_nm


def test_world_seed_is_the_same_rig_and_the_settings_apply():
    a, b = _world(1, world_seed=9)[3], _world(2, world_seed=9)[3]
    assert a == b
    w = _world(3, engine_map_dev_rel_sd=0.0, engine_ageing_loss_frac=0.04, ambient_day=(25.0, 99.0, 0.0))[3]
    assert w.true_over_map(2500.0) == pytest.approx(0.96)
