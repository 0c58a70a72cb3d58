"""Auto-tune of the speed hold on the simulated rig (through the real output code): it finds the tuned
kp on the standard brake, and half of it on a brake twice as stiff (the plant's gain doubled)."""

import json
from dataclasses import replace

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.control.planfile import plan_from_text
from dyno.sim.rig_params import RigParams

PLAN = plan_from_text('schema = "dyno.plan/1"\nname = "tune"\nmode = "steps"\n[[step]]\nkind = "contact"\n'
                      '[[step]]\nkind = "identify"\nsetpoint = 3000.0\nrepeats = 2\n', "tune.toml")


def _identify(tmp_path, name, params=None) -> dict:
    out = tmp_path / name
    run_test(RunSpec(sim=True, seed=1, plan=PLAN, out_dir=out, mock_pins=True, sim_params=params))
    docs = [json.loads(line) for line in (out / "documents.jsonl").read_text().splitlines()]
    (found,) = [d for d in docs if d["type"] == "identify"]
    return found


def test_identify_finds_the_tuned_gain_and_scales_with_the_plant(tmp_path):
    std = _identify(tmp_path, "std")
    assert std["ok"] and std["applied"] and std["kp_before"] == 12.0
    assert std["kp_identified"] == pytest.approx(12.0, rel=0.25) and std["spread"] <= 0.5, std
    stiff = _identify(tmp_path, "stiff", replace(RigParams(), brake_spring_rate_n_per_mm=13.0))
    assert stiff["ok"]
    assert stiff["gain_rel_per_s"] / std["gain_rel_per_s"] == pytest.approx(2.0, rel=0.3)
    assert stiff["kp_identified"] / std["kp_identified"] == pytest.approx(0.5, rel=0.3)
