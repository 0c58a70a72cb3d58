"""The sim's engagement from the primary clamp, driven-side loss and torque-zero drift (dyno.sim.driven)."""

import math

import numpy as np
import pytest

from dyno.sim.driven import characterisation_truth
from dyno.sim.physics import RigModel
from dyno.sim.rig_params import RigParams

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

FAST = dict(belt_efficiency_source="loss_model")


def _model(**kw):
    m = RigModel(RigParams(**FAST, **kw), seed=3)
    m.start_engine()
    m.step(3.0)
    return m


def test_engagement_is_where_the_flyweights_overcome_the_spring_preload():
    m = _model()
    cvt, eng = m.cvt, m.engagement
    c = cvt._lookup(cvt._c, cvt.x_min)
    s_p = cvt._lookup(cvt._sp, cvt.x_min)
    fr = cvt.friction  # the world's: the ramps take (h_p) of the flyweights' force, the bushing its share
    n0 = math.sqrt((s_p + 0.5 * fr.sheave_friction_n) / ((1.0 - fr.ramp_friction_frac) * c))  # closing clamp zero
    assert n0 > math.sqrt(s_p / c) + 10.0  # later than the frictionless balance the advisor assumes
    assert eng.capacity_nm(n0 - 1.0, cvt.x_min) == 0.0 < eng.capacity_nm(n0 + 1.0, cvt.x_min)
    truth = characterisation_truth(m)
    assert n0 < truth["engagement_rpm_true"] < n0 + 15.0  # the light load needs a little clamp
    # on a slow ramp the secondary starts to turn there, not before
    first = None
    for k in range(800):
        m.throttle_frac = min(1.0, 0.01 * k * 0.05)
        m.step(0.05)
        tr = m.truth()
        if tr.rpm_secondary > 0.5:
            first = tr.rpm_primary
            break
    assert first is not None and abs(first - truth["engagement_rpm_true"]) < 10.0


def test_heavier_flyweights_engage_lower_and_the_former_ramp_stays_available():
    stock = characterisation_truth(_model())["engagement_rpm_true"]
    heavy = characterisation_truth(_model(cvt_tune_path="calibration/tunes/heavy-flyweights.toml"))
    assert heavy["engagement_rpm_true"] == pytest.approx(stock / math.sqrt(0.262 / 0.228), rel=0.01)
    old = RigModel(RigParams(**FAST, cvt_engagement_model="smoothstep"))
    assert old.engagement is None and old.cvt.clutch_capacity_nm_at(2000.0) > 0.0
    with pytest.raises(ValueError, match="cvt_engagement_model"):
        RigModel(RigParams(**FAST, cvt_engagement_model="magic"))
    with pytest.raises(ValueError, match="driven_loss_nm"):
        RigModel(RigParams(**FAST, driven_loss_nm=(0.1, -1.0, 0.0)))


def test_driven_loss_decelerates_the_uncoupled_secondary_as_stated():
    a, b, c = 0.10, 4e-4, 1.2e-6
    m = _model(driven_loss_nm=(a, b, c))
    m.throttle_frac = 1.0
    m.step(6.0)
    m.throttle_frac = 0.0
    m.engine_enabled = False
    while m.truth().clutch_locked or m.truth().rpm_primary > 1500:  # until the belt lets go
        m.step(0.05)
    p = m.params
    g = p.gear_ratio_brake_per_secondary
    j = p.secondary_inertia_kg_m2 + p.brake_shaft_inertia_kg_m2 * g * g
    w0 = m.truth().rpm_secondary * math.pi / 30
    m.step(0.2)
    w1 = m.truth().rpm_secondary * math.pi / 30
    w = 0.5 * (w0 + w1)
    # (plus the default driveline's drag: RigParams driveline_loss_*, no load share with the belt let go)
    expected = (a + b * w + c * w * w + g * p.brake_residual_drag_nm + m.driveline_loss_nm(w)) / j
    assert -(w1 - w0) / 0.2 == pytest.approx(expected, rel=0.02)


def test_zero_drift_moves_the_adc_at_rest():
    drift = 1.0  # N m per minute
    m = RigModel(RigParams(**FAST, adc_zero_drift_nm_per_min=drift), seed=5)

    def mean_torque(seconds):
        ev = [e for e in m.step(seconds) if e.channel == "adc"]
        codes = np.array([e.code for e in ev], dtype=float)
        return (codes.mean() - m.params.adc_offset_counts) / m.params.adc_gain_counts_per_nm

    first = mean_torque(10.0)
    m.step(40.0)
    last = mean_torque(10.0)
    assert last - first == pytest.approx(drift * 50.0 / 60.0, abs=0.05)
