"""``dyno ui --sim --mock-pins --drill estop-twice@...`` (issue 36): an E-stop, a re-arm, a second E-stop.  The
E-stop input used to trip once per session: the second opening safed the outputs but recorded no stop, and the
run ended as an error that blocked the next re-arm.  Here each opening is an ``estop`` abort of its own run."""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from dyno.control.api import State
from dyno.session.drills import parse_drill
from dyno.ui.session import LiveOptions, LiveSession

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "e2e"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_e2e_wiring_drills import wired_rig  # noqa: E402
from test_ui_session_rest import _until  # noqa: E402


def test_a_second_estop_after_a_rearm_is_an_estop_abort(tmp_path):
    async def scenario():
        s = LiveSession(LiveOptions(sim=True, speed=8.0, seed=2, out_dir=tmp_path / "run", mock_pins=True,
                                    rig_path=wired_rig(tmp_path), drills=[parse_drill("estop-twice@armed+1")]))
        s.start()
        try:
            assert await _until(lambda: s.controller.state is State.ABORTED, 60), s.controller.state
            first = s.controller
            assert first.aborts[0]["cause"] == "estop"
            assert await _until(lambda: s.rearm_refusal() is None, 60), s.rearm_refusal()
            new_dir, msg = s.rearm()
            assert new_dir is not None, msg
            assert await _until(lambda: s.controller.aborts, 60), s.controller.state
            a = s.controller.aborts[0]
            assert s.controller is not first and a["cause"] == "estop" and "opening 2" in a["detail"]
            m = s.sim.model
            assert await _until(lambda: m.pads_off and m.actuator_dir == 0, 30), m.actuator_mm
            assert not m.engine_enabled and m.throttle_frac == 0.0
            assert s.controller.act.released  # the driver's verdict agrees with the physics
        finally:
            await s.close("test")

    asyncio.run(scenario())
