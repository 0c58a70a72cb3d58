"""An unknown start is not a release (issue 49, item 3), as the user runs it: the simulated brake started applied
(``--sim-brake-start MM``), the end switch stuck closed from the first frame, K3 fitted as shipped.

Judged by the physics' own record of the start-up (``outputs.startup_released_at_s``: the pads first left the
rotor; ``outputs.ignition_enabled_at_s``: the kill chain first closed), not by what the driver says.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.control.plans import plan_named
from dyno.session.root import RunSpec, run_test
from dyno.sim.rig_params import RigParams

REPO = Path(__file__).resolve().parents[2]
FULL_STROKE_S = 8.0  # hardware/rig.toml [actuator] full_stroke_s


def _dyno(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "DYNO_STATE_DIR": str(cwd / "state")}
    return subprocess.run([sys.executable, "-m", "dyno", *args], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=900)


def test_an_applied_brake_and_a_stuck_closed_switch_the_chain_closes_only_after_the_pads_are_off(tmp_path):
    from tests.e2e.test_e2e_wiring_drills import wired_rig

    rig = wired_rig(tmp_path, k3=True)
    p = _dyno("run", "--sim", "--headless", "--json", "--mock-pins", "--sim-brake-start", "20", "--rig", str(rig),
              "--drill", "endswitch-stuck-closed@0", "--out", str(tmp_path / "run"), cwd=tmp_path)
    assert p.returncode in (0, 3), p.stderr[-2000:]
    r = json.loads(p.stdout)
    o = r["outputs"]
    released, enabled = o["startup_released_at_s"], o["ignition_enabled_at_s"]
    assert released is not None and released > 0.0  # it started on the rotor (20 mm, free travel 1 mm)
    assert enabled is None or enabled >= released, o
    assert enabled is None or enabled >= FULL_STROKE_S  # the switch's closed reading did not shorten the wait
    named = "end-of-travel switch" in p.stderr or any("switch" in a.get("detail", "") for a in r["aborts"])
    assert named, p.stderr[-2000:]
    assert any(f["channel"] == "end_switch" and "stuck closed" in f["detail"] for f in r["rig_faults"]), r["rig_faults"]
    assert o["pads_off_rotor"] and r["rig_safe"]


@pytest.mark.parametrize("start_mm", [0.0, 20.0])
def test_the_simulated_driver_holds_the_ignition_too(tmp_path, start_mm):
    r = run_test(RunSpec(sim=True, seed=1, plan=plan_named("speed-hold"), out_dir=tmp_path / "run",
                            sim_params=RigParams(ideal=True, brake_start_mm=start_mm)))
    assert r["state"] == "done", r["reason"]
    o = r["outputs"]
    released, enabled = o["startup_released_at_s"], o["ignition_enabled_at_s"]
    assert released == 0.0 if start_mm == 0.0 else 0.0 < released < FULL_STROKE_S
    assert enabled >= released and enabled >= FULL_STROKE_S  # the honest cost: the brake's position was unknown
    assert r["test_time_s"] <= 100.0  # (counted from GO: the hold comes before it)


def test_a_brake_start_outside_the_travel_is_one_line_and_exit_2(tmp_path):
    p = _dyno("run", "--sim", "--headless", "--sim-brake-start", "41", "--out", str(tmp_path / "run"), cwd=tmp_path)
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0 and "--sim-brake-start" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "run").exists()
