"""`dyno ui --sim --mock-pins --drill ...` as the operator runs it: a real process in tmux, on a real event loop.

The drill strikes mid-test (the pads biting); the run directory must then record what `dyno run --json`
would: the drill with its hazard verdict, the latency in true time from the onset (not from detection),
and the physical outputs — the pads off the rotor, the actuator off — read from the simulated physics."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest


REPO = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_ui_mock_pins_drill_records_the_physical_safe_state(tmp_path, terminal):
    out = tmp_path / "run"
    cmd = " ".join([sys.executable, "-m", "dyno", "ui", "--sim", "--mock-pins", "--speed", "4",
                    "--drill", "adc-stuck@loaded+2", "--out", str(out)]) + " ; echo EXITED=$? ; sleep 30"
    name = terminal(cmd, size=(120, 40), cwd=tmp_path, env={"HOME": str(tmp_path), "PYTHONPATH": str(REPO)})
    try:
        name.wait("ARMED", 150)  # (a busy 2-core machine: the app and the sim start slowly)
        name.keys("g")
        name.wait("GO", 10)
        name.keys("y")
        screen = name.wait(["ABORTED", "rig SAFE"], 180)
        assert "sensor_fault" in screen
        name.keys("q")
        name.wait("EXITED=", 60)
    finally:
        name.close()
    docs = [json.loads(line) for line in (out / "documents.jsonl").read_text().splitlines() if line.strip()]
    safety = [d for d in docs if d.get("type") == "safety"]
    assert safety, "the UI run left no safety record"
    s = safety[-1]
    assert s["drills"][0]["drill"] == "adc-stuck@loaded+2" and s["drills"][0]["hazard_arose"] is True
    a = s["aborts"][0]
    assert a["cause"] == "sensor_fault"
    # true time from the physical onset: the stuck ADC is seen after 50 conversions (0.4 s at 125 Hz)
    assert 0.3 <= a["latency_s"] <= 2.0, a
    assert a["detection_s"] == pytest.approx(a["latency_s"], abs=0.05), a
    o = s["outputs"]
    assert s["rig_safe"] is True and o["pads_off_rotor"] is True and o["brake_actuator"] == "stopped"
    assert o["brake_position_at_safe_mm"] > 1.0  # the brake was on the rotor when the fault came
    assert o["release_s"] <= o["release_bound_s"], o
    assert o["driver_released"] is True and o["brake_estimate"] == 0.0  # the real-rig output code's own view
