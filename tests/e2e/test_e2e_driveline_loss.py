"""The default simulated rig's driveline between the CVT and the gauge (RigParams driveline_loss_*), judged by
the sim's truth: the gauge reads the belt's output less it; a coast-down measures its drag; the coast-down's
loss added back brings the efficiency to the belt's own less the load share no coast-down can see."""

from dataclasses import replace

import pytest

from dyno.analysis.coastdown import driven_loss_keys, load_driven_loss
from dyno.session.root import RunSpec, run_test
from dyno.control.api import TestPlan
from dyno.control.plans import plan_named
from dyno.sim.physics import RigModel
from dyno.sim.rig_params import RigParams
from dyno.sim.rig_params import DEFAULT_DRIVELINE_LOSS, driveline_loss_of

from .conftest import tare_error

DRAG_NM, PER_KRPM_NM, LOAD_FRAC = DEFAULT_DRIVELINE_LOSS


@pytest.mark.quick
def test_the_default_rig_has_a_driveline_and_the_ideal_one_none():
    assert driveline_loss_of(RigParams()) == DEFAULT_DRIVELINE_LOSS
    assert driveline_loss_of(RigParams(ideal=True)) == (0.0, 0.0, 0.0)
    assert driveline_loss_of(RigParams(ideal=True, driveline_loss_load_frac=0.02)) == (0.0, 0.0, 0.02)
    m = RigModel(RigParams(belt_efficiency_source="loss_model"), seed=2)
    m.start_engine()
    m.throttle_frac = 1.0
    m.step(3.0)
    m.actuator_dir = 1
    m.step(4.0)
    m.actuator_dir = 0
    m.step(3.0)  # steady, loaded
    t = m.truth()
    expect = DRAG_NM + PER_KRPM_NM * t.rpm_secondary / 1000 + LOAD_FRAC * t.torque_secondary_nm
    assert t.driveline_loss_nm == pytest.approx(expect, rel=0.02)
    # the gauge (on the brake shaft) sees the belt's output less the driveline; the truth's efficiency is the belt's
    assert t.torque_brake_shaft_nm * m._g == pytest.approx(t.torque_secondary_nm - t.driveline_loss_nm, abs=0.05)
    assert t.efficiency == pytest.approx(t.power_out_w / t.power_in_w)


#: a heavier driveline than the default (a worn chain, tight bearings: twice the default's drag), so the
#: correction is judged on a loss well above the coast-down's own resolution (~0.5 pp at these loads: the
#: released pads' residual drag it also sees); the default's drag is half this (bench_fidelity, the 2019 logs)
HEAVY_DRAG_NM, HEAVY_PER_KRPM_NM = 2 * DRAG_NM, 2 * PER_KRPM_NM


def test_coast_down_measures_the_driveline_drag_and_corrects_the_efficiency(tmp_path):
    # perfect knowledge otherwise (engine, sensor, day): the driveline alone
    params = RigParams(ideal=True, driveline_loss_drag_nm=HEAVY_DRAG_NM,
                       driveline_loss_drag_nm_per_krpm=HEAVY_PER_KRPM_NM, driveline_loss_load_frac=LOAD_FRAC)
    cd = run_test(RunSpec(sim=True, seed=5, out_dir=tmp_path / "cd", plan=plan_named("coast-down"),
                             sim_params=params))
    assert cd["state"] == "done"
    fit = cd["loss_fit"]
    # the fitted drag is the driveline's (plus the released brake's residual drag, in the truth too)
    for rpm, f, t, s, y in zip(fit["rpm_grid"], fit["torque_nm"], cd["loss_torque_true_nm"], fit["torque_ci95_nm"],
                               fit["torque_sys95_nm"]):
        assert t >= HEAVY_DRAG_NM + HEAVY_PER_KRPM_NM * rpm / 1000  # the truth holds the driveline's drag
        assert abs(f - t) <= s + y + 0.02
    loss = load_driven_loss(tmp_path / "cd" / "driven_loss.json")
    run = run_test(RunSpec(sim=True, seed=5, out_dir=tmp_path / "run", sim_params=params,
                              plan=replace(TestPlan(), max_points=6, max_measure_s=6.0)))
    # the tare (one zero that every point shares) judged on its own bound, its error taken out of each point
    assert abs(run["torque_tare"]["zero_nm"]) <= 2.6 * run["torque_tare"]["u_nm"], run["torque_tare"]
    inside, left = 0, []
    for p in run["points"]:
        assert p["driveline_loss_true_nm"] > HEAVY_DRAG_NM
        k = driven_loss_keys(p, loss)
        raw = p["efficiency"] - p["efficiency_true"]
        assert raw < -0.01  # the driveline makes the reading low
        # what the coast-down cannot see: the load share (the belt's output times LOAD_FRAC)
        unseen = -LOAD_FRAC * p["efficiency_true"]
        fixed = k["efficiency_loss_corrected"] - p["efficiency_true"] - tare_error(run, p)
        assert abs(fixed - unseen) < abs(raw) / 2  # the correction takes at least half the error away
        left.append(fixed - unseen)
        inside += abs(fixed - unseen) <= k["efficiency_loss_corrected_ci95"]
    # the correction is a systematic one: across the points it lands within 1 pp; each point's own noise (its
    # efficiency alone ~±1.3 pp at the lightest load) is judged by its stated interval
    assert abs(sum(left) / len(left)) <= 0.01, left
    assert inside >= 0.8 * len(run["points"])
