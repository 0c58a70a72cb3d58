"""Issue 52 item 4: effects the simulated world has that the host's statements do not describe exactly —
a gauge slope that drifts within a run as the brake warms the shaft, an air sensor that reads warm — judged
on the physics (the ADC's codes against the true gauge torque, the chip's reading against the day)."""

from __future__ import annotations

import numpy as np
import pytest

from dyno.sim.bme280_chip import SimBME280
from dyno.sim.world import World

pytestmark = pytest.mark.quick


def _gauge_vs_truth(d, settle_s: float = 6.0):
    """(ADC torque / true gauge torque − 1, the rotor's rise above the day) over 2 s of a steady load."""
    events, truths = d.run(settle_s)
    events, truths = d.run(2.0)
    p = d.model.params
    codes = np.array([e.code for e in events if e.channel == "adc"], float)
    torque = (codes.mean() - p.adc_offset_counts) / p.adc_gain_counts_per_nm
    truth = float(np.mean([x.torque_secondary_nm - x.driveline_loss_nm for x in truths]))
    rise = float(np.mean([x.rotor_temp_c for x in truths])) - p.ambient_temp_c
    return torque / truth - 1.0, rise


def test_the_gauge_slope_drifts_with_the_rotors_warm_up_within_a_run(make_driver):
    tempco = 1e-4
    drifting = make_driver(seed=31, adc_gain_rotor_tempco_per_k=tempco)
    steady = make_driver(seed=31)
    for d in (drifting, steady):
        d.start_full_throttle()
        d.brake_step(2.5, 4.0)
    early, rise_early = _gauge_vs_truth(drifting, 0.0)
    early_ref, _ = _gauge_vs_truth(steady, 0.0)
    for d in (drifting, steady):  # more time under load: the rotor (and the shaft beside it) warms
        d.run(30.0)
    late, rise_late = _gauge_vs_truth(drifting, 0.0)
    late_ref, _ = _gauge_vs_truth(steady, 0.0)
    assert rise_late > rise_early + 20.0, (rise_early, rise_late)  # the brake did warm the rotor
    # the drifting gauge reads high by tempco × the rise (the steady one's error subtracted: noise, ripple)
    assert early - early_ref == pytest.approx(tempco * rise_early, abs=0.003)
    assert late - late_ref == pytest.approx(tempco * rise_late, abs=0.003)
    assert late - late_ref > early - early_ref + 0.5 * tempco * (rise_late - rise_early)  # it grew over the run


def test_the_air_sensor_reads_warm_by_its_bias_on_top_of_its_own_error():
    w = World(18.0, 95.0, 40.0, 1.0)
    plain, warm = SimBME280(w, seed=9), SimBME280(w, seed=9, temp_bias_c=2.0)
    assert warm.reading()[0] - plain.reading()[0] == pytest.approx(2.0)
    assert warm.reading()[1:] == plain.reading()[1:]  # pressure and humidity untouched
    # over many chips the bias is the mean error: the host's rectangular ±1 °C about the reading misses it
    errs = [SimBME280(w, seed=s, temp_bias_c=2.0).reading()[0] - 18.0 for s in range(200)]
    assert np.mean(errs) == pytest.approx(2.0, abs=0.1) and np.mean(np.abs(errs) > 1.0) > 0.9
