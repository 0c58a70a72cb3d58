"""A re-armed live session's next run is wired at construction as the first (issue 50): the next run log's write
error aborts the next controller (not the ended one), the watchdog's beat and the kill-lead warning are the new
controller's from its constructor, the polls kick the one watchdog in force, and the test runs through the root's
RunningTest."""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from dyno.control.controller import State
from dyno.session.root import RunningTest
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
