"""`dyno run`: a signal while the rig is still being built (a terminal closed during start-up) is held and
ends the run once it exists — abort record, safety record, closed log — instead of killing the process
with a run directory that holds only its `start` record (issue 23)."""

from __future__ import annotations

import pytest

import json
import os
import signal

import dyno.session.root
from dyno.session.root import RunSpec, run_test
from dyno.control.plans import plan_named

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def test_signal_during_build_ends_the_run_safe_with_its_records(tmp_path, monkeypatch):
    real_build = dyno.session.root.build
    seen = {}

    def build_then_signalled(*args, **kwargs):
        ctx = real_build(*args, **kwargs)
        seen["ctx"] = ctx
        os.kill(os.getpid(), signal.SIGTERM)  # (the default action would end this test process)
        return ctx

    monkeypatch.setattr(dyno.session.root, "build", build_then_signalled)
    before = signal.getsignal(signal.SIGTERM)
    out = tmp_path / "run"
    r = run_test(RunSpec(sim=True, seed=21, speed=None, out_dir=out, plan=plan_named("coast-down"),
                            handle_signals=True))
    assert r["state"] == "aborted" and r["aborts"][0]["cause"] == "signal", r["aborts"]
    assert "SIGTERM" in r["aborts"][0]["detail"]
    m = seen["ctx"].sim.model  # the physics: safe
    assert m.throttle_frac == 0.0 and not m.engine_enabled and m.pads_off and m.actuator_dir == 0
    docs = [json.loads(x) for x in (out / "documents.jsonl").read_text().splitlines() if x.strip()]
    types = [d["type"] for d in docs]
    assert types[0] == "start" and types[-2:] == ["safety", "stop"] and "abort" in types, types
    assert signal.getsignal(signal.SIGTERM) == before
