"""A signal while the UI session is still being built (a terminal closed during start-up): the session
acts on it once it exists — abort, safe state, the app told to quit — and a simulated session that never
polled leaves no half-made run directory (issue 23: a directory with a `start` record alone was left)."""

from __future__ import annotations

import asyncio
import os
import signal

import dyno.app
from dyno.control.controller import State
from dyno.ui.session import LiveOptions, LiveSession


def test_signal_during_build_aborts_once_built_and_leaves_nothing(tmp_path, monkeypatch):
    real_build = dyno.app.build
    built = {}

    def build_then_signalled(*args, **kwargs):
        ctx = real_build(*args, **kwargs)  # the run directory exists now, its log has its `start`
        built["run_dir"] = ctx.writer.run_dir
        assert (ctx.writer.run_dir / "documents.jsonl").is_file()
        os.kill(os.getpid(), signal.SIGTERM)  # (SIGHUP would also detach this process's terminal)
        return ctx

    monkeypatch.setattr(dyno.app, "build", build_then_signalled)
    before = signal.getsignal(signal.SIGTERM)

    async def scenario():
        s = LiveSession(LiveOptions(sim=True, speed=4.0, seed=11, out_dir=tmp_path / "run"))
        codes = []
        s.on_signal = codes.append  # (as the app hooks it, right after the session is built)
        for _ in range(40):
            if codes:
                break
            await asyncio.sleep(0.05)
        assert codes == [128 + signal.SIGTERM]
        assert s.controller.state is State.ABORTED and s.controller.aborts[0]["cause"] == "signal"
        s.start()  # the app's start-up may still call it: nothing starts after the signal
        assert not s.started and not {t.get_name() for t in s._tasks} & {"poller", "controller"}
        m = s.sim.model  # the physics: nothing moved, nothing runs
        assert m.throttle_frac == 0.0 and not m.engine_enabled and m.actuator_mm <= m.brake.a0_mm
        await s.close("signal")
        return s

    s = asyncio.run(scenario())
    assert s.run_dir_removed and not built["run_dir"].exists() and s.run_dirs == []
    assert signal.getsignal(signal.SIGTERM) == before  # the process's own handler back
