"""Fault drills in the calibration wizard (`dyno calibrate --sim --drill ...`): aborted, banner, nothing written."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from dyno.session.drills import parse_drill
from dyno.ui.calibrate_app import CalibrateApp, CalibrateOptions
from tests.screens import screen_text

SIZE = (80, 24)


async def _until_aborted(app):
    """Drive the wizard (defaults, then 'c' at each load) until a drill aborts it: (abort, screen text)."""
    async with app.run_test(size=SIZE) as pilot:
        await pilot.press("enter", "enter")  # radius, masses: the defaults; taring starts
        t_end = time.monotonic() + 30
        while app.wizard.aborted is None and time.monotonic() < t_end:
            if not app.wizard.collecting and app.wizard.aborted is None:
                await pilot.press("c")
            await pilot.pause(0.1)
        await pilot.pause(0.4)
        shot = screen_text(app)
        await pilot.press("q")  # the user's way out (leaving run_test otherwise never returns)
        return app.wizard.aborted, shot


@pytest.mark.parametrize("drill, cause", [("adc-error@1", "sensor_fault"), ("adc-stuck@1", "sensor_fault"),
                                          ("bus-lost@1", "comms_lost")])
def test_calibration_drill_aborts_and_writes_nothing(tmp_path, drill, cause):
    hist = tmp_path / "hist.csv"

    async def scenario():
        app = CalibrateApp(CalibrateOptions(sim=True, seed=4, speed=2.0, n_samples=100, settle_samples=60,
                                            history_path=hist, drills=[parse_drill(drill, engine=False)]))
        aborted, shot = await _until_aborted(app)
        return aborted, shot, app.cal_ctx.trip

    aborted, screen, trip = asyncio.run(scenario())
    assert aborted is not None and aborted[0] == cause
    assert "ABORTED" in screen and "rig SAFE" in screen
    assert not hist.exists()


def test_calibration_refuses_engine_drills():
    from dyno.errors import ConfigError

    with pytest.raises(ConfigError, match="--drill"):
        parse_drill("overtemp@1", engine=False)


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_calibrate_drill_in_a_real_terminal(tmp_path):
    session = f"dyno-cal-{uuid.uuid4().hex[:8]}"
    cmd = (f"{sys.executable} -m dyno calibrate --sim --speed 2 --history {tmp_path / 'h.csv'} "
           f"--drill adc-stuck@1 ; echo EXITED=$? ; sleep 30")
    subprocess.run(["tmux", "new-session", "-d", "-x", "100", "-y", "30", "-s", session, cmd], check=True,
                   timeout=20, env={"TERM": "xterm-256color", "PATH": "/usr/bin:/bin", "HOME": str(tmp_path),
                                    "PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    try:
        t_end = time.monotonic() + 60
        screen = ""
        while time.monotonic() < t_end and "ABORTED" not in screen:
            screen = subprocess.run(["tmux", "capture-pane", "-p", "-t", session], capture_output=True, text=True,
                                    timeout=20).stdout
            time.sleep(0.3)
        assert "ABORTED (sensor_fault)" in screen and "rig SAFE" in screen, screen
        subprocess.run(["tmux", "send-keys", "-t", session, "q"], timeout=20)
        t_end = time.monotonic() + 20
        while time.monotonic() < t_end and "EXITED=" not in screen:
            screen = subprocess.run(["tmux", "capture-pane", "-p", "-t", session], capture_output=True, text=True,
                                    timeout=20).stdout
            time.sleep(0.3)
        assert "EXITED=0" in screen, screen
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True, timeout=20)
    assert not (tmp_path / "h.csv").exists()


@pytest.mark.parametrize("drill, what", [("adc-error:input@1", "input torque ADC error bit"),
                                         ("adc-stuck:input@1", "input torque ADC stuck")])
def test_input_channel_calibration_drill_aborts_and_writes_nothing(tmp_path, drill, what):
    """The engine-side converter's faults end its calibration as the brake-side one's do (the same monitor)."""
    hist = tmp_path / "hist.csv"
    rig = Path(__file__).resolve().parents[2] / "hardware" / "rig-input-torque.toml"

    async def scenario():
        app = CalibrateApp(CalibrateOptions(sim=True, seed=4, speed=2.0, n_samples=100, settle_samples=60,
                                            history_path=hist, rig_path=rig, channel="input", radius_m=0.2,
                                            masses="2,4,6,8,10", drills=[parse_drill(drill, engine=False)]))
        return await _until_aborted(app)

    aborted, screen = asyncio.run(scenario())
    assert aborted is not None and aborted[0] == "sensor_fault" and what in aborted[1], aborted
    assert "ABORTED" in screen and "rig SAFE" in screen
    assert not hist.exists()
