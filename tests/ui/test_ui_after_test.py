"""`dyno ui` ends a test as `dyno run` does, through the same code (dyno.session.after): the torque zero read at
rest, the run's summary and safety document, the log closed and report.html written when the test ends, while
the screen is still up; and a clean start loses no event before GO (driven by Textual's pilot, in process)."""

from __future__ import annotations

import asyncio
import json
import re
from dataclasses import replace

from dyno.control.api import State, TestPlan
from dyno.ui.live_app import LiveApp
from dyno.ui.session import LiveOptions
from tests.screens import screen_text, wait_for

SPEED = 8.0
SIZE = (80, 24)


def _docs(run_dir) -> list[dict]:
    return [json.loads(x) for x in (run_dir / "documents.jsonl").read_text().splitlines() if x.strip()]


def test_ui_run_dir_has_the_zero_check_summary_and_report_before_quitting(tmp_path):
    run_dir = tmp_path / "run"
    plan = replace(TestPlan(), max_points=2, max_measure_s=4.0)
    seen: dict = {}

    async def scenario():
        app = LiveApp(LiveOptions(sim=True, speed=SPEED, seed=2, out_dir=run_dir, plan=plan))
        async with app.run_test(size=SIZE) as pilot:
            assert await wait_for(pilot, lambda: app.session is not None
                                  and app.session.controller.state is State.ARMED, 60), "never armed"
            s = app.session
            await pilot.press("g")
            await pilot.press("y")
            assert await wait_for(pilot, lambda: s.controller.state in (State.DONE, State.ABORTED), 240), \
                s.controller.reason
            assert s.controller.state is State.DONE, s.controller.aborts
            # the screen is still up: the run directory is complete before any quit
            assert await wait_for(pilot, lambda: (run_dir / "report.html").is_file(), 120), "no report.html"
            assert app.is_running and not s.closed
            seen["docs"] = _docs(run_dir)
            seen["report"] = (run_dir / "report.html").read_text()
            seen["report_mtime"] = (run_dir / "report.html").stat().st_mtime_ns
            # the world at the end: the engine cut and the secondary at rest (the zero is read there)
            seen["secondary_w_true"] = s.sim.model._w_s
            seen["safe"] = s.sim.actuators.is_safe
            seen["screen"] = screen_text(app)
            await pilot.press("q")
            await pilot.pause(0.5)

    asyncio.run(scenario())
    docs = seen["docs"]
    types = [d["type"] for d in docs]
    # the after-test zero check, as dyno run records it: before GO and after the last point, at rest
    zero = [d for d in docs if d["type"] == "torque_zero"]
    assert len(zero) == 1, types
    zc = zero[0]
    after = zc["after"]
    assert "why" not in after or after.get("torque_nm") == after.get("torque_nm"), after
    # the simulated load cell has no drift here: the true zero is 0 N m, within the reading's own 95 % band
    assert abs(after["torque_nm"]) <= after["ci95_nm"] + 0.05, after
    assert abs(zc["drift_nm"]) <= zc["drift_ci95_nm"] + 0.05 and not zc["flagged"], zc
    # the summary's safety document, then the end record, both written when the test ended
    assert "safety" in types and types[-1] == "stop", types
    assert docs[-1]["exit_status"] == "success"
    safety = next(d for d in docs if d["type"] == "safety")
    assert safety.get("rig_safe") is True and seen["safe"], safety
    # the report has its "Torque zero" section, and the quit did not write it again
    assert "<h2>Torque zero</h2>" in seen["report"]
    assert (run_dir / "report.html").stat().st_mtime_ns == seen["report_mtime"]
    assert "DONE" in seen["screen"] and seen["secondary_w_true"] == 0.0


def test_ui_a_clean_start_loses_no_event_before_go(tmp_path, speed=SPEED):
    """The simulated Nano's ring does not overflow while the session is built and the first screen drawn:
    the rig's time starts with the first poll (truth: the device's own drop counter and the time it first
    served a frame), and the screen's "lost" reads 0, as a headless run's does."""

    async def scenario():
        from dyno.control.plans import plan_named

        # (`dyno ui`'s default plan: the closed-loop speed hold)
        app = LiveApp(LiveOptions(sim=True, speed=speed, seed=0, out_dir=tmp_path / "run", plan=plan_named("speed-hold")))
        async with app.run_test(size=SIZE) as pilot:
            assert await wait_for(pilot, lambda: app.session is not None
                                  and app.session.controller.state is State.ARMED, 60), "never armed"
            s = app.session
            await pilot.pause(1.0)
            fw = s.sim.firmware
            first_served_s = min(fw.first_served_s.values())
            out = (first_served_s, fw.events_dropped, s.poller.reader.events_lost)
            assert await wait_for(pilot, lambda: re.search(r"lost +0 events", screen_text(app)), 5), screen_text(app)
            out += (screen_text(app),)
            # GO asks in the plan's words: the default plan holds speed setpoints, it does not step the brake
            await pilot.press("g")
            assert await wait_for(pilot, lambda: "Start the test?" in screen_text(app), 5)
            out += (screen_text(app),)
            await pilot.press("n")
            await pilot.press("q")
            await pilot.pause(0.3)
        return out

    first_served_s, dropped_true, lost, screen, dialog = asyncio.run(scenario())
    # every row of the fields column fits with its label: the link's rows are one each, none wrapped
    lines = screen.splitlines()
    assert len(lines) == 24 and all(len(x) <= 80 for x in lines)
    fields = [x[:32].strip() for x in lines]
    k = next(i for i, x in enumerate(fields) if x.startswith("CRC/NACK"))
    assert re.fullmatch(r"CRC/NACK +\d+/\d+  rejected \d+", fields[k]), fields[k]
    assert re.fullmatch(r"lost +\d+ events", fields[k + 1]) and fields[k + 2].startswith("Nano run"), fields[k:k + 3]
    words = " ".join(re.sub(r"[│┃]", " ", dialog).split())  # (the dialog's text wraps inside its border)
    assert "HOLDS the secondary at 19 speed setpoints" in words and "stepping" not in words, words
    # the first frame went out within the first polls of the rig's time zero (the physics no longer runs while
    # the session is built and the first screen drawn: that was ~5 s of rig time at x8, 150-700 events dropped)
    assert first_served_s < 1.0, first_served_s
    assert dropped_true == 0 and lost == 0
