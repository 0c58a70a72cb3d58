"""The points measure torque from the zero read at rest before GO: a bridge offset that moved since the
calibration (the thesis history's intercepts scatter by ~60 counts, 0.6 N m) does not bias them —
judged against the simulator's true secondary torque, with the tare on and, as the control, off."""

from __future__ import annotations

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.control.plans import plan_named
from dyno.sim.rig_params import RigParams
from scipy import stats
from tests.e2e.test_e2e_honest_numbers import SHORT_PLAN


def _run(tmp_path, tare: bool):
    plan = tmp_path / "short.toml"
    plan.write_text(SHORT_PLAN)
    rig = tmp_path / f"rig-{tare}.toml"
    from tests.e2e.test_e2e_honest_numbers import REPO

    text = (REPO / "hardware" / "rig.toml").read_text()
    assert "\ntare = true " in text
    rig.write_text(text.replace("\ntare = true ", f"\ntare = {str(tare).lower()} ", 1))
    # an offset 3 N m off the calibration's (300 counts), nothing else different from the host's knowledge
    params = RigParams(ideal=False, engine_map_dev_rel_sd=0.0, adc_gain_drift_rel_sd=0.0,
                       adc_offset_drift_counts_sd=300.0, ambient_day=(25.0, 99.0, 0.0), world_seed=14)
    res = run_test(RunSpec(sim=True, seed=3, sim_params=params, plan=plan_named(str(plan)), rig_path=rig,
                              out_dir=tmp_path / f"run-{tare}"))
    assert abs(res["sim_world"]["adc_offset_drift_counts"]) > 100  # (world seed 14: +175 counts, +1.6 N m)
    return res


def _at_gauge(p: dict, world: dict) -> float:
    """The true torque the gauge sees: the belt's output less the driveline (RigParams driveline_loss_*), as
    the world's sensor reads it against the calibration's slope (its slope follows the day's temperature:
    adc_gain_drift_rel, +0.125 % at 25 degC)."""
    return (p["torque_secondary_true_nm"] - p["driveline_loss_true_nm"]) * (1.0 + world["adc_gain_drift_rel"])


def _tol_nm(p: dict, u_tare_nm: float = 0.0) -> float:
    """0.15 N m, or the point's own 95 % statistical half-width where that is wider (its mean torque's standard
    error from the spectrum, with the tare's standard uncertainty): a point whose torque swings +-6 N m with
    the firing cannot be asked to average closer than its statistics allow."""
    t95 = float(stats.t.ppf(0.975, max(1, p["torque_secondary_sem_dof"])))
    return max(0.15, t95 * (p["torque_secondary_sem_nm"] ** 2 + u_tare_nm ** 2) ** 0.5)


def test_tare_removes_an_offset_that_moved(tmp_path):
    res = _run(tmp_path, tare=True)
    assert res["torque_tare"]["zero_nm"] == pytest.approx(res["sim_world"]["adc_offset_drift_counts"] / 108.188,
                                                          abs=0.15)
    u_tare = res["torque_tare"]["u_nm"]
    for p in res["points"]:  # (the gauge sees the belt's output less the rig's driveline after it)
        assert p["torque_secondary_nm"] == pytest.approx(_at_gauge(p, res["sim_world"]), abs=_tol_nm(p, u_tare))


def test_without_the_tare_the_offset_is_in_every_point(tmp_path):
    res = _run(tmp_path, tare=False)
    off = res["sim_world"]["adc_offset_drift_counts"] / 108.188
    assert "torque_tare" not in res
    for p in res["points"]:
        assert p["torque_secondary_nm"] - _at_gauge(p, res["sim_world"]) == pytest.approx(off, abs=_tol_nm(p))
