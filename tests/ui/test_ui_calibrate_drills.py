"""Fault drills in the calibration wizard (`dyno calibrate --sim --drill ...`): aborted, banner, nothing written."""

from __future__ import annotations

import asyncio
import shutil
import sys
import time
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
def test_calibrate_drill_in_a_real_terminal(tmp_path, terminal):
    cmd = (f"{sys.executable} -m dyno calibrate --sim --speed 2 --history {tmp_path / 'h.csv'} "
           f"--drill adc-stuck@1 ; echo EXITED=$? ; sleep 30")
    session = terminal(cmd, size=(100, 30),
                       env={"HOME": str(tmp_path), "PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    try:
        screen = session.wait("ABORTED", 60)
        assert "ABORTED (sensor_fault)" in screen and "rig SAFE" in screen, screen
        session.keys("q")
        session.wait("EXITED=0", 20)
    finally:
        session.close()
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
