"""A signal while the UI session is still being built (a terminal closed during start-up): the session
acts on it once it exists — abort, safe state, the app told to quit — and a simulated session that never
polled leaves no half-made run directory (issue 23: a directory with a `start` record alone was left)."""

from __future__ import annotations

import asyncio
import os
import signal

import dyno.session.root
from dyno.control.api import State
from dyno.ui.session import LiveOptions, LiveSession


def test_signal_during_build_aborts_once_built_and_leaves_nothing(tmp_path, monkeypatch):
    real_build = dyno.session.root.build
    built = {}

    def build_then_signalled(*args, **kwargs):
        ctx = real_build(*args, **kwargs)  # the run directory exists now, its log has its `start`
        built["run_dir"] = ctx.writer.run_dir
        assert (ctx.writer.run_dir / "documents.jsonl").is_file()
        os.kill(os.getpid(), signal.SIGTERM)  # (SIGHUP would also detach this process's terminal)
        return ctx

    monkeypatch.setattr(dyno.session.root, "build", build_then_signalled)
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
        assert not s.started and not s.running.started and not {t.get_name() for t in s._tasks} & {"controller"}
        m = s.sim.model  # the physics: nothing moved, nothing runs
        assert m.throttle_frac == 0.0 and not m.engine_enabled and m.actuator_mm <= m.brake.a0_mm
        await s.close("signal")
        return s

    s = asyncio.run(scenario())
    assert s.run_dir_removed and not built["run_dir"].exists() and s.run_dirs == []
    assert signal.getsignal(signal.SIGTERM) == before  # the process's own handler back


def test_quit_right_after_a_watchdog_trip_before_go_records_the_rig_safe(tmp_path):
    """A watchdog trip before GO powers the release stroke; a quit at once must let it end before the record
    is written (it said `rig_safe: false`, "actuator releasing", though the pads were never on the rotor)."""
    import json

    from dyno.session.drills import parse_drill

    async def scenario():
        s = LiveSession(LiveOptions(sim=True, speed=4.0, seed=12, out_dir=tmp_path / "run",
                                    drills=[parse_drill("loop-stall:900@2")]))
        s.start()
        for _ in range(600):
            if s.controller.state is State.ABORTED:
                break
            await asyncio.sleep(0.05)
        assert s.controller.go_s is None and s.controller.aborts[0]["cause"] == "watchdog", s.controller.aborts
        await s.close("operator quit")  # at once, as the soak's operator did
        m = s.sim.model
        assert m.actuator_dir == 0 and m.pads_off and m.throttle_frac == 0.0 and not m.engine_enabled
        return s

    s = asyncio.run(scenario())
    docs = [json.loads(x) for x in (tmp_path / "run" / "documents.jsonl").read_text().splitlines() if x.strip()]
    (safety,) = [d for d in docs if d["type"] == "safety"]
    assert safety["rig_safe"] is True, safety.get("rig_unsafe_because")
    assert safety["outputs"]["brake_actuator"] != "releasing"
