"""`dyno run --sim --plan engagement|coast-down --json` as real processes, judged by the sim's truth."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.control.safety import SafetyLimits

ROOT = Path(__file__).resolve().parents[2]
TUNES = ("cvtech-stock", "heavy-flyweights", "stiff-primary-spring")


def _run(tmp_path, *args):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--json", "--out", str(tmp_path / "run"),
                           *map(str, args)], capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


@pytest.mark.parametrize("tune", TUNES)
def test_engagement_plan_recovers_the_simulated_cvt(tmp_path, tune):
    d = _run(tmp_path, "--plan", "engagement", "--tune", ROOT / "calibration" / "tunes" / f"{tune}.toml")
    assert d["state"] == "done" and d["points"] == []
    for key in ("engagement_rpm", "shift_out_rpm"):
        assert abs(d[key] - d[f"{key}_true"]) <= 50.0, (key, d[key], d[f"{key}_true"])
        assert d[f"{key}_ci95"] > 0
    assert abs(d["full_shift_ratio"] / d["full_shift_ratio_true"] - 1) <= 0.01
    assert d["full_shift_ratio_ci95"] > 0
    # lock-up comes after engagement, shift-out after lock-up, and the plan kept the tune's prediction
    assert d["engagement_rpm"] < d["lockup_rpm"] < d["shift_out_rpm"]
    assert d["tune"] == tune and d["predicted"]["engagement_rpm"] > 0
    assert d["back_shift"]["ratio_after"] > d["back_shift"]["ratio_before"]  # a load step back-shifts
    assert 0 < d["test_time_s"] < 300
    report = (tmp_path / "run" / "report.html").read_text()
    assert "<h2>Characterisation</h2>" in report and "<h2>Torque zero</h2>" in report and "sim truth" in report
    assert 'id="fig-ramps"' in report and 'id="fig-efficiency"' not in report  # its own figure, no empty plots
    # the figures are reproduced exactly from the raw events on disk (as a replay would)
    from dyno.control.plans.characterise import characterise_ramp
    from dyno.protocol import v1
    from dyno.runlog.reader import load_run

    run = load_run(tmp_path / "run")
    ramp = run.docs("ramp")[0]
    st = run.streams
    t0, t1 = ramp["t_start_us"], ramp["t_end_us"]
    again = characterise_ramp(st.edge_window(v1.CH_PRIMARY, t0 - 2_000_000, t1),
                              st.edge_window(v1.CH_SECONDARY, t0 - 2_000_000, t1), t0, t1)
    for key in ("engagement_rpm", "lockup_rpm", "shift_out_rpm", "full_shift_ratio", "full_shift_ratio_ci95"):
        assert again[key] == d[key]
    # shift-out flatness across load: three ramps, heavier loads shift out higher (the helix), each as the truth
    rows = d["shift_out_vs_load"]
    if d["engagement_rpm"] > SafetyLimits().secondary_check_primary_rpm - 60:
        # a tune engaging near the Hall safety check's speed: a heavier load would hold the secondary past
        # it, so the plan does not load it further (and says so)
        assert len(rows) == 1
        return
    assert len(rows) == 3 and rows[0]["torque_secondary_nm"] < rows[1]["torque_secondary_nm"] \
        < rows[2]["torque_secondary_nm"]
    for r in rows:
        assert abs(r["shift_out_rpm"] - r["shift_out_rpm_true"]) <= 50.0
        assert abs(r["engagement_rpm"] - r["engagement_rpm_true"]) <= 50.0
    fl, fl_true = d["shift_out_flatness"], d["shift_out_flatness_true"]
    assert fl["slope_rpm_per_nm"] > 0
    assert abs(fl["slope_rpm_per_nm"] - fl_true["slope_rpm_per_nm"]) <= fl["slope_ci95_rpm_per_nm"]
    docs = [json.loads(line) for line in (tmp_path / "run" / "documents.jsonl").read_text().splitlines()]
    stored = [x for x in docs if x.get("type") == "characterisation"]
    assert len(stored) == 1 and stored[0]["engagement_rpm"] == d["engagement_rpm"]  # with the run


def test_engagement_differs_between_tunes_as_the_physics_says(tmp_path):
    """Heavier flyweights engage lower, a stiffer primary spring higher (the sim's engagement is the tune's)."""
    from dyno.sim.physics import RigModel
    from dyno.sim.rig_params import RigParams
    from dyno.sim.driven import characterisation_truth

    true = {t: characterisation_truth(RigModel(RigParams(belt_efficiency_source="loss_model",
                                                         cvt_tune_path=f"calibration/tunes/{t}.toml")))
            for t in TUNES}
    assert true["heavy-flyweights"]["engagement_rpm_true"] < true["cvtech-stock"]["engagement_rpm_true"] \
        < true["stiff-primary-spring"]["engagement_rpm_true"]


def test_coast_down_recovers_the_parasitic_loss(tmp_path):
    d = _run(tmp_path, "--plan", "coast-down", "--sim-driven-loss", "0.10,4e-4,1.2e-6")
    assert d["state"] == "done"
    fit = d["loss_fit"]
    # (the default rig's driveline drag adds to this loss: the uncoupled coast is shorter, 7 revolutions on
    # seeds 0-1, 13 without it; the fit is still within 0.1 % of the truth)
    assert fit["n_revolutions"] >= 6 and fit["rpm_max"] > 1.6 * fit["rpm_min"]
    assert d["loss_torque_max_rel_error"] <= 0.05
    # the fitted curve's band covers the truth
    for f, t, s, y in zip(fit["torque_nm"], d["loss_torque_true_nm"], fit["torque_ci95_nm"], fit["torque_sys95_nm"]):
        assert abs(f - t) <= s + y
    assert 'id="fig-loss"' in (tmp_path / "run" / "report.html").read_text()
    stored = json.loads((tmp_path / "run" / "driven_loss.json").read_text())
    assert stored["loss_fit"]["coefficients"] == fit["coefficients"]


def test_driven_loss_added_back_recovers_the_cvt_efficiency(tmp_path):
    """A rig with a loss the gauge does not see reads efficiency low; the coast-down's loss, added back
    with its uncertainty, brings the points back to the CVT's own (the sim's truth)."""
    from dataclasses import replace

    from dyno.analysis.coastdown import driven_loss_keys, load_driven_loss
    from dyno.session.root import RunSpec, run_test
    from dyno.control.api import TestPlan
    from dyno.control.plans import plan_named
    from dyno.sim.rig_params import RigParams

    params = RigParams(driven_loss_nm=(0.10, 4e-4, 1.2e-6), ideal=True)  # (perfect knowledge: the loss alone)
    cd = run_test(RunSpec(sim=True, seed=4, out_dir=tmp_path / "cd", plan=plan_named("coast-down"),
                             sim_params=params))
    assert cd["state"] == "done"
    loss = load_driven_loss(tmp_path / "cd" / "driven_loss.json")
    run = run_test(RunSpec(sim=True, seed=4, out_dir=tmp_path / "run", sim_params=params,
                              plan=replace(TestPlan(), max_points=6, max_measure_s=6.0)))
    inside = 0
    for p in run["points"]:
        k = driven_loss_keys(p, loss)
        raw, fixed = p["efficiency"] - p["efficiency_true"], k["efficiency_loss_corrected"] - p["efficiency_true"]
        assert raw < -0.01  # the unseen loss makes the measured efficiency low
        assert abs(fixed) < abs(raw)
        inside += abs(fixed) <= k["efficiency_loss_corrected_ci95"]
    assert inside >= 0.8 * len(run["points"])
    # a bad loss file: one line naming the file and field, exit 2, nothing written
    bad = tmp_path / "bad.json"
    bad.write_text('{"schema": "dyno.driven_loss/1", "loss_fit": {}}')
    proc = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--driven-loss", str(bad), "--out",
                           str(tmp_path / "never")], capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert proc.returncode == 2 and "bad.json: loss_fit" in proc.stderr and len(proc.stderr.splitlines()) == 1
    assert not (tmp_path / "never").exists()


def test_a_clutch_engaging_below_idle_is_refused_safely(tmp_path):
    """Flyweights so heavy the secondary already turns at idle: nothing to characterise, said in one line."""
    from dyno.session.root import RunSpec, run_test
    from dyno.control.plans import plan_named
    from dyno.sim.rig_params import RigParams

    tune = tmp_path / "very-heavy.toml"
    tune.write_text((ROOT / "calibration" / "tunes" / "cvtech-stock.toml").read_text()
                    .replace("mass_each_kg = 0.228", "mass_each_kg = 0.400"))
    r = run_test(RunSpec(sim=True, seed=1, out_dir=tmp_path / "run", plan=plan_named("engagement"),
                            tune_path=tune, sim_params=RigParams(cvt_tune_path=str(tune))))
    assert r["state"] == "aborted" and r["rig_safe"]
    assert "engages below idle" in r["aborts"][0]["detail"]
