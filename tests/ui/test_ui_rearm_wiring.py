"""A re-armed live session's next run is wired at construction as the first (issue 50): the next run log's write
error aborts the next controller (not the ended one), the watchdog's beat and the kill-lead warning are the new
controller's from its constructor, the polls kick the one watchdog in force, and the test runs through the root's
RunningTest."""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from dyno.control.api import State
from dyno.session.running import RunningTest
from dyno.session.safety import _WatchdogKick
from dyno.ui.session import LiveOptions, LiveSession

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_ui_session_rest import _until  # noqa: E402


def test_a_rearmed_run_is_wired_at_construction_and_its_log_error_aborts_it(tmp_path):
    async def scenario():
        s = LiveSession(LiveOptions(sim=True, speed=8.0, seed=2, out_dir=tmp_path / "run"))
        assert isinstance(s.running, RunningTest) and not s.running.started
        s.start()
        try:
            assert s.running.started
            assert await _until(lambda: s.controller.state is State.ARMED, 30), s.controller.reason
            first, first_wd = s.controller, s.ctx.watchdog
            assert len(first.heartbeat_hooks) == 1 and s._on_controller in first.listeners
            s.estop("test")
            assert await _until(lambda: s.rearm_refusal() is None, 60), s.rearm_refusal()
            new_dir, msg = s.rearm()
            assert new_dir is not None, msg
            ctrl = s.controller
            assert ctrl is not first and ctrl is s.ctx.controller and ctrl.writer is s.ctx.writer
            # given to its constructor: the watchdog's beat, the kill-lead warning before the face's listener
            assert len(ctrl.heartbeat_hooks) == 1 and ctrl.listeners[-1] == s._on_controller
            assert len(ctrl.listeners) == 2 and ctrl.listeners[0].__qualname__.startswith("uncuttable_warning")
            kicks = [fn for fn in s.poller.listeners if isinstance(fn, _WatchdogKick)]
            assert len(kicks) == 1 and kicks[0].wd is s.ctx.watchdog and s.ctx.watchdog is not first_wd
            assert first._on_poll not in s.poller.listeners and ctrl._on_poll in s.poller.listeners
            # the points' systematic terms read the run's own tare (the next controller's, not the ended one's)
            first.tare, ctrl.tare = {"u_nm": 0.0}, {"u_nm": 2.0}
            point = dict(first.points[0]) if first.points else {
                "torque_secondary_nm": 10.0, "efficiency": 0.8, "efficiency_sem": 0.002, "efficiency_ci95": 0.004,
                "rpm_primary": 3000.0, "rpm_secondary": 3000.0, "throttle_frac": 1.0, "power_in_w": 4000.0}
            point["torque_secondary_nm"] = 10.0
            ctrl.point_hooks[0](point, 0.0, 1.0)
            assert point["efficiency_sys95_calibration"] > 0.8 * 1.96 * 0.2 * 0.9, point  # u 2 N·m of 10 N·m: 20 %
            assert await _until(lambda: ctrl.state is State.WAIT_ENGINE or ctrl.state is State.ARMED, 30)
            # the next log's write error, given to its RunWriter at construction: the next controller aborts
            aborts_before = list(first.aborts)
            s.ctx.writer.inject_disk_full()
            s.ctx.writer.doc("note", text="a write on a full disk")
            assert ctrl.aborts and ctrl.aborts[0]["cause"] == "disk_full", ctrl.aborts
            assert str(new_dir) in ctrl.aborts[0]["detail"] and first.aborts == aborts_before
        finally:
            await s.close("test")
        assert s.running.poll_task.done()

    asyncio.run(scenario())
