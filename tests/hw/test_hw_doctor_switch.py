"""Shipped is the recommended wiring (issue 49, item 4): `dyno doctor` names an undeclared safety input, and with
K3 fitted still checks the end switch — stuck open at the stop without moving, stuck closed by one apply step
with the kill chain closed for that step alone — judged on the simulated physics, and as a real process."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.hw.doctor import run_diagnosis
from dyno.session.doctor_rig import doctor_spec
from dyno.hw.mockpins import END_SWITCH_CLOSES_MM
from dyno.rig.config import DEFAULT_RIG_PATH, load_rig

REPO = Path(__file__).resolve().parents[2]


def test_every_shipped_rig_file_declares_the_safety_inputs():
    for path in sorted((REPO / "hardware").glob("*.toml")):
        cfg = load_rig(path)
        assert cfg.pins.estop_input == 22 and cfg.pins.brake_released_input == 27, path


@pytest.mark.quick
def test_an_undeclared_safety_input_is_a_named_fail(tmp_path, capsys):
    from dyno.cli import main

    text = DEFAULT_RIG_PATH.read_text()
    p = tmp_path / "rig.toml"
    p.write_text("\n".join(line for line in text.splitlines()
                           if not line.startswith(("estop_input", "brake_released_input"))) + "\n")
    assert main(["doctor", "--sim", "--rig", str(p)]) == 1
    out = capsys.readouterr().out
    fails = [line for line in out.splitlines() if line.split()[:1] == ["FAIL"]]
    assert any("pins.estop_input not declared" in line for line in fails), out
    assert any("pins.brake_released_input not declared" in line for line in fails), out


@pytest.mark.quick
def test_with_k3_the_step_closes_the_chain_for_itself_alone_with_the_engine_stopped(tmp_path, monkeypatch):
    monkeypatch.setenv("DYNO_STATE_DIR", str(tmp_path))
    cfg = load_rig(None)
    assert cfg.actuator.brake_hold_relay
    spec = doctor_spec(cfg, sim=True, mock_pins=True)
    model = spec.pin_factory.sim.model
    report = run_diagnosis(spec)
    assert report.ok, report.render()
    log = model.ignition_log  # (t, on, by) at every change of the chain, the physics' own record
    on = [(t, i) for i, (t, o, _) in enumerate(log) if o]
    first_on = [t for t, i in on if i > 0]  # closings after the doctor claimed the pins (it started closed)
    assert len(first_on) == 1, log  # the chain closed once: for the step
    t_on = first_on[0]
    t_off = next(t for t, o, _ in log if not o and t > t_on)
    assert t_off - t_on <= cfg.actuator.step_s + 2 * cfg.actuator.relay_settle_s + 0.5  # that step alone
    assert not model.engine_running and model.pads_off and model.actuator_mm == pytest.approx(0.0, abs=1e-6)
    assert model.startup_released_at_s == 0.0


def _doctor(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "DYNO_STATE_DIR": str(cwd / "state")}
    return subprocess.run([sys.executable, "-m", "dyno", "doctor", *args], capture_output=True, text=True, cwd=cwd,
                          env=env, timeout=600)


@pytest.mark.parametrize("drill,says", [("endswitch-stuck-closed", "stuck closed"),
                                        ("endswitch-stuck-open", "stuck open"),
                                        ("endswitch-bounce", "chatters")])
def test_the_shipped_rig_doctor_finds_each_switch_fault_as_a_real_process(tmp_path, drill, says):
    p = _doctor("--sim", "--mock-pins", "--drill", drill, cwd=tmp_path)
    assert p.returncode == 1, p.stdout + p.stderr
    fails = [line for line in p.stdout.splitlines() if line.split()[:1] == ["FAIL"]]
    assert len(fails) == 1 and "end switch" in fails[0] and "pins.brake_released_input" in fails[0], p.stdout
    assert says in fails[0], fails
    assert "Traceback" not in p.stderr


def test_the_switch_opens_out_of_the_stop_in_the_physics_the_doctor_judged():
    """(the twin's switch closes within END_SWITCH_CLOSES_MM of the stop: a 0.25 s step moves ~1.25 mm)"""
    cfg = load_rig(None)
    assert cfg.actuator.step_s * 40.0 / cfg.actuator.full_stroke_s > END_SWITCH_CLOSES_MM
