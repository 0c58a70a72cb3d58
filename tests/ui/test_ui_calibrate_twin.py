"""``dyno calibrate --sim --mock-pins``: the calibration wizard with the rig's outputs through the Pi's own code
(HardwareRig: GpioActuators, the watchdog thread) on the wiring twin, the fixture's brake actuator behind it.

The brake is left 5 mm onto the rotor by the last run; the start-up release must end with the pads off and the
actuator de-energised (on the rig nothing ticked the outputs during a calibration: the enable stayed on for
the whole of it), a drill's trip leaves the rig safe, and the driver's verdict agrees with the physics."""

from __future__ import annotations

import asyncio
import time

from dyno.session.drills import parse_drill
from dyno.ui.calibrate_app import CalibrateApp, CalibrateOptions

SIZE = (80, 24)


def test_calibration_through_the_twin_releases_the_brake_and_ends_safe(tmp_path):
    hist = tmp_path / "hist.csv"
    seen: dict = {}

    async def scenario():
        app = CalibrateApp(CalibrateOptions(sim=True, seed=4, speed=8.0, n_samples=100, settle_samples=60,
                                            history_path=hist, mock_pins=True,
                                            drills=[parse_drill("bus-lost@20", engine=False)]))
        async with app.run_test(size=SIZE) as pilot:
            act, wiring = app.cal_ctx.hw.actuators, app.cal_ctx.twin.sim
            seen["start_mm"] = wiring.model.start_mm  # (the release may have begun before the app let us look)
            await pilot.press("enter", "enter")
            t_end = time.monotonic() + 30
            while True:
                # (first: the release ends ~2 s of rig time in; the drill comes at 20 s, 2.5 s of wall time at
                # x8 -- a loaded machine starting the app late once saw the drill's new release first)
                if "released_s" not in seen and act.released:
                    seen["released_s"] = wiring.model.t_s
                    seen["outs_released"] = wiring.outputs()
                if app.wizard.aborted is not None or time.monotonic() >= t_end:
                    break
                if not app.wizard.collecting:
                    await pilot.press("c")
                await pilot.pause(0.05)
            seen["aborted"] = app.wizard.aborted
            await pilot.press("q")
        seen["end"] = wiring.outputs()
        seen["driver"] = act.output_states()

    asyncio.run(scenario())
    assert seen["start_mm"] == 5.0
    # the start-up release ended while the calibration ran: pads off, actuator off (the driver said so, the
    # physics agrees)
    assert "released_s" in seen and seen["outs_released"]["pads_off_rotor"]
    assert seen["outs_released"]["brake_actuator"] == "stopped"
    assert seen["aborted"] is not None and seen["aborted"][0] == "comms_lost"
    assert seen["end"]["safe"] and seen["end"]["brake_position_mm"] == 0.0, seen["end"]
    assert seen["driver"]["released"] is True and seen["driver"]["pins"] == "released"
    assert not hist.exists()
