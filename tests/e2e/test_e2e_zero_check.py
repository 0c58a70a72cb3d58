"""Torque zero checks on the simulated rig with a drifting zero (RigParams.adc_zero_drift_nm_per_min)."""

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

from dyno.session.root import RunSpec, run_test
from dyno.control.api import TestPlan as StepPlan
from dyno.sim.rig_params import RigParams

ROOT = Path(__file__).resolve().parents[2]


def test_drift_is_measured_flagged_and_corrected(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text((ROOT / "hardware" / "rig.toml").read_text().replace("correct = false", "correct = true"))
    drift_per_min = 2.0
    res = run_test(RunSpec(sim=True, seed=2, out_dir=tmp_path / "run", rig_path=rig,
                              plan=replace(StepPlan(), max_points=5, max_measure_s=4.0),
                              sim_params=RigParams(adc_zero_drift_nm_per_min=drift_per_min, ideal=True)))
    assert res["state"] == "done"
    zc = res["torque_zero"]
    true_drift = drift_per_min * (zc["after"]["t_mid_s"] - zc["before"]["t_mid_s"]) / 60.0
    # a 95 % interval misses one run in twenty by design: seeds 1-8 put the estimate at 0.05-1.07 of its CI95
    # from the truth (seed 2, this one, 1.07 since the belt model's solver changed the sim's tables by 1e-6);
    # a drift the check did not see would be 2.05 N m off (~16 CI95)
    assert abs(zc["drift_nm"] - true_drift) <= 1.5 * zc["drift_ci95_nm"]
    assert zc["flagged"] and "drifted" in zc["note"]
    # the linear correction removes the drift's error from every point, down to the zero readings' own
    # uncertainty (each 4 s reading: +-0.09 N m, 95 %) carried into the point's torque
    zci = max(zc["before"]["ci95_nm"], zc["after"]["ci95_nm"])
    for p in res["points"]:
        raw = abs(p["efficiency"] - p["efficiency_true"])
        fixed = abs(p["efficiency_zero_corrected"] - p["efficiency_true"])
        allowed = p["efficiency_ci95"] + p["efficiency"] * zci / p["torque_secondary_nm"]
        assert fixed < 0.5 * raw and fixed <= allowed, (raw, fixed, allowed)
    docs = [json.loads(x) for x in (tmp_path / "run" / "documents.jsonl").read_text().splitlines()]
    assert [d for d in docs if d.get("type") == "torque_zero"]


def test_no_drift_no_flag_as_a_real_process(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--json", "--plan", "coast-down", "--out",
                           str(tmp_path / "run")], capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr
    zc = json.loads(proc.stdout)["torque_zero"]
    assert not zc["flagged"] and abs(zc["drift_nm"]) <= zc["drift_ci95_nm"] + 0.02
