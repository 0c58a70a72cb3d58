"""The calibration wizard screen driven by Textual's pilot on the simulated fixture."""

from __future__ import annotations

import asyncio
import time

import pytest

from dyno.analysis.calibration_history import load_history
from dyno.ui.calibrate_app import CalibrateApp, CalibrateOptions
from dyno.ui.calibration_wizard import Phase
from tests.screens import screen_text

SIZE = (80, 24)
HELP = "Enter/c collect  r redo  a accept  x reject  q quit │ SPACE/^C E-STOP"


def _opts(tmp_path, **kw):
    base = dict(sim=True, seed=4, speed=4.0, n_samples=100, settle_samples=60, history_path=tmp_path / "hist.csv")
    base.update(kw)
    return CalibrateOptions(**base)


async def _until(pilot, cond, timeout_s: float = 10.0) -> None:
    t_end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < t_end:
        await pilot.pause(0.05)


def test_ui_calibrate_full_procedure_accept_appends(tmp_path):
    # The default 500 samples a step: with 100 the tare means scatter 0.08 N·m each and the zero-drift
    # check would sit at 2.3 standard errors of its noise (refused ~1 run in 40 before it weighed the noise).
    async def scenario():
        shots = {}
        app = CalibrateApp(_opts(tmp_path, speed=6.0, n_samples=500, settle_samples=125))
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.5)
            shots["setup"] = screen_text(app)
            await pilot.press("enter", "enter")  # radius, masses: the defaults
            await pilot.pause(0.3)
            shots["tare"] = screen_text(app)
            w = app.wizard
            t_end = time.monotonic() + 90
            while w.phase is not Phase.REVIEW and time.monotonic() < t_end:
                if not w.collecting:
                    await pilot.press("c")
                await pilot.pause(0.1)
            await pilot.pause(0.4)
            shots["review"] = screen_text(app)
            assert w.acceptable, f"not acceptable: {w.rejection}"
            await pilot.press("a")
            # wait for the modal rather than a fixed pause: CI's 2 busy cores can be slow
            await _until(pilot, lambda: "Append this calibration" in screen_text(app))
            shots["confirm"] = screen_text(app)
            await pilot.press("y")
            await _until(pilot, lambda: w.phase is Phase.ACCEPTED and "ACCEPTED" in screen_text(app))
            shots["accepted"] = screen_text(app)
            fx = app.rig.fixture
            await pilot.press("q")
        return shots, w, fx

    shots, w, fx = asyncio.run(scenario())
    assert w.phase is Phase.ACCEPTED
    for name, text in shots.items():
        lines = text.splitlines()
        assert len(lines) == 24 and all(len(line) <= 80 for line in lines), name
        assert "E-STOP" in text and HELP in lines[-1], name
    assert "SETUP" in shots["setup"] and "5,10,20,30,40" in shots["setup"]
    assert "TARE BEFORE" in shots["tare"] and "NO mass hanging" in shots["tare"]
    assert " 6 load   40.0  30.87" in shots["tare"] and "11 tare" in shots["tare"]
    for label in ("slope", "icpt", "R²", "non-lin", "hyst", "zero drift", "residual counts vs N·m"):
        assert label in shots["review"], label
    assert "Append this calibration" in shots["confirm"]
    assert "ACCEPTED" in shots["accepted"]
    (entry,) = load_history(tmp_path / "hist.csv")
    assert entry.n_samples == 500 * 9 and entry.lever_arm_m == 0.15
    assert "inconclusive" not in shots["review"]  # 500 samples resolve the 0.25 N·m zero check
    # timing under load varies the noise realisation: looser than test_ui_calibration_wizard's 2.5 s.e.
    assert abs(entry.slope_counts_per_nm - fx.true_gain_counts_per_nm) < 4 * w.fit.slope_se_counts_per_nm


def test_ui_calibrate_refuses_two_loads_and_says_why(tmp_path):
    async def scenario():
        app = CalibrateApp(_opts(tmp_path, masses="10,20"))
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.3)
            await pilot.press("enter", "enter")
            await pilot.pause(0.2)
            text = screen_text(app)
            phase = app.wizard.phase
            await pilot.press("escape")  # leave the input: the keys drive the wizard
            await pilot.press("a")  # nothing to accept
            await pilot.pause(0.1)
            text2 = screen_text(app)
            await pilot.press("ctrl+c")  # E-STOP, not quit
            await pilot.pause(0.1)
            running = app.is_running
            text3 = screen_text(app)
            await pilot.press("ctrl+q")  # quits from anywhere, even an input
        return phase, text, text2, running, text3

    phase, text, text2, running, text3 = asyncio.run(scenario())
    assert phase is Phase.SETUP
    assert "2 distinct load(s): at least 3 are needed" in text
    assert "cannot accept" in text2
    assert running and "E-STOP" in text3 and "no outputs" in text3
    assert not (tmp_path / "hist.csv").exists()


def test_ui_calibrate_space_with_the_field_focused_is_estop(tmp_path):
    async def scenario():
        app = CalibrateApp(_opts(tmp_path))
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.3)
            focused = app.focused.id
            await pilot.press("space", "ctrl+c")
            await pilot.pause(0.2)
            value = app.query_one("#radius").value
            await pilot.press("q")
        return focused, value, app.wizard.aborted

    focused, value, aborted = asyncio.run(scenario())
    assert focused == "radius" and value == "0.15"  # nothing typed into the field
    assert aborted is not None and aborted[0] == "estop"


def test_ui_calibrate_c_in_a_number_field_acts_instead_of_typing(tmp_path):
    async def scenario():
        app = CalibrateApp(_opts(tmp_path))
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.3)
            await pilot.press("c")  # the radius field has the focus: "c" is no number, it is "collect"
            await pilot.pause(0.3)
            value = app.query_one("#radius").value
            phase = app.wizard.phase
            await pilot.press("q")
        return value, phase

    value, phase = asyncio.run(scenario())
    assert value == "0.15" and phase is not Phase.SETUP


def test_an_error_inside_the_running_app_propagates_instead_of_hanging(tmp_path):
    """Textual's run_test shuts the app down with App._shutdown when its body raises: the wizard must not
    shadow it (it did: the app never exited and a failing assertion hung the suite)."""
    async def scenario():
        app = CalibrateApp(_opts(tmp_path))
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.3)
            raise RuntimeError("an assertion inside the app's context")

    # an app that did not shut down would hold the error until wait_for's timeout, which raises TimeoutError instead
    with pytest.raises(RuntimeError, match="inside the app's context"):
        asyncio.run(asyncio.wait_for(scenario(), 300))


def test_ui_calibrate_input_channel_without_its_converter_says_so(tmp_path):
    """The rig file declares the input channel but the firmware announces no second converter (old firmware,
    or not fitted: the fixture without it): the screen says so instead of waiting for conversions."""
    from pathlib import Path

    rig = Path(__file__).resolve().parents[2] / "hardware" / "rig-input-torque.toml"

    async def scenario():
        app = CalibrateApp(_opts(tmp_path, channel="input", rig_path=rig, radius_m=0.2, masses="2,4,6,8,10",
                                 fixture_kw={"input_fitted": False}))
        async with app.run_test(size=SIZE) as pilot:
            await _until(pilot, lambda: "NO input converter" in screen_text(app))
            shot = screen_text(app)
            await pilot.press("q")
        return shot

    shot = asyncio.run(scenario())
    assert "NO input converter (firmware)" in shot and "input" in shot.splitlines()[0]
    assert not (tmp_path / "hist.csv").exists()
