"""The simulated rig is its own engine, sensor and day (dyno.sim.world): drawn per seed with the spread
its parameters state, never the host's files; the ideal world is the host's knowledge exactly."""

from __future__ import annotations

import statistics

import numpy as np
import pytest

from dyno.analysis.calibration_history import load_history
from dyno.analysis.systematic import calibration_rel_u
from dyno.resources import DEFAULT_CALIBRATION
from dyno.sim.engine import EngineMap
from dyno.sim.rig_params import RigParams
from dyno.sim.world import realise

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

MAP = EngineMap.from_csv("calibration/engine_maps/baja-10hp-representative.csv")


def _world(seed, **kw):
    return realise(RigParams(**kw), seed, MAP.rpm, MAP.torque_nm)


def test_draws_have_the_stated_spread():
    ws = [_world(s)[3] for s in range(400)]
    sd_rel = RigParams().engine_map_dev_rel_sd
    for rpm in (1800.0, 2600.0, 3400.0):
        sd = statistics.pstdev(w.engine_dev_rel_at(rpm) for w in ws)
        assert 0.86 * sd_rel < sd < 1.14 * sd_rel  # +- 3 standard errors of an sd from 400 draws
    # the gauge: re-seating scatter and the thermal drift from the calibration's temperature to the day's
    p = RigParams()
    thermal = [p.adc_gain_tempco_per_k * (w.temp_c - p.adc_calibration_temp_c) for w in ws]
    scatter = [w.adc_gain_drift_rel - t for w, t in zip(ws, thermal)]
    assert 0.86 * p.adc_gain_drift_rel_sd < statistics.pstdev(scatter) < 1.14 * p.adc_gain_drift_rel_sd
    assert max(abs(t) for t in thermal) > 0.003  # a 5 or 35 C day moves the slope by ~0.4 %
    days = [(w.temp_c, w.pressure_kpa, w.rh_pct) for w in ws]
    assert min(d[0] for d in days) >= 5.0 and max(d[0] for d in days) <= 35.0
    assert 80.0 < min(d[1] for d in days) and max(d[1] for d in days) < 105.0


def test_the_world_spreads_are_the_simulators_own_not_the_hosts():
    """The simulator's spreads come from its own basis (rig_params), not from the host's stated terms: the
    engine's differs from the map term the host states; the gauge's total spread (re-seating + thermal) is
    not the history's figure, but the history's figure, a standard deviation of four slopes, is one that four
    calibrations of the simulated gauge could give (chi-square 95 % interval, 3 degrees of freedom)."""
    from dyno.analysis.engine_map import load_engine_map
    from dyno.rig.config import load_rig

    p = RigParams()
    stated_map = load_engine_map(p.engine_map_path).stated_u_rel
    if stated_map is None:
        stated_map = load_rig("hardware/rig.toml").uncertainty.engine_map_rel
    assert abs(p.engine_map_dev_rel_sd - stated_map) > 0.002
    history = load_history(DEFAULT_CALIBRATION)
    stated_cal = calibration_rel_u(history, history[-1])
    ws = [_world(s)[3] for s in range(400)]
    sim_total = statistics.pstdev(w.adc_gain_drift_rel for w in ws)
    assert sim_total != pytest.approx(stated_cal, rel=0.02)
    chi2_lo, chi2_hi = 0.216, 9.348  # chi-square(3) 2.5 % and 97.5 % points
    assert sim_total * (chi2_lo / 3) ** 0.5 < stated_cal < sim_total * (chi2_hi / 3) ** 0.5


def test_bench_world_knobs_move_the_truth():
    """A calibration moved by 3 % shifts every seed's true slope by 3 %; the knobs are off by default."""
    p = RigParams()
    assert p.world_adc_gain_shift_rel == 0.0 and p.world_driveline_loss_frac == 0.0
    for seed in (1, 2, 3):
        a, b = _world(seed)[3], _world(seed, world_adc_gain_shift_rel=0.03)[3]
        assert b.adc_gain_drift_rel - a.adc_gain_drift_rel == pytest.approx(0.03, abs=1e-12)


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
