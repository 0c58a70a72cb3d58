"""Live run screen driven headless by Textual's pilot on the simulated rig (paced faster than real time)."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dyno.control.controller import State
from dyno.control.controller import TestPlan as Plan
from dyno.ui.live_app import LiveApp
from dyno.ui.live_model import RateMeter, fmt, ideal_engine_rpm, overlay_inputs, temp_colour
from dyno.ui.session import LiveOptions, scaled_plan

SPEED = 8.0  # 8x real time: a first point within ~10 s of wall time on a loaded 2-core machine
SIZE = (80, 24)


def screen_text(app) -> str:
    """The rendered screen as plain text, one line per row (a structural snapshot)."""
    return "\n".join(strip.text for strip in app.screen._compositor.render_strips())


async def wait_for(pilot, cond, timeout_s: float, step_s: float = 0.2) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if cond():
            return True
        await pilot.pause(step_s)
    return cond()


def test_ui_live_go_points_estop(tmp_path):
    """Start a simulated run, GO (confirmed), see points appear on screen, E-STOP: safe state and cause shown."""

    async def scenario():
        app = LiveApp(LiveOptions(sim=True, speed=SPEED, seed=0, out_dir=tmp_path / "run"))
        async with app.run_test(size=SIZE) as pilot:
            s = None
            assert await wait_for(pilot, lambda: app.session is not None, 5)
            s = app.session
            assert await wait_for(pilot, lambda: s.controller.state is State.ARMED, 30), (s.controller.state, s.controller.aborts)
            # GO asks first; "n" declines and nothing moves.
            await pilot.press("g")
            await pilot.pause(0.1)
            assert "Start the test?" in screen_text(app)
            await pilot.press("n")
            await pilot.pause(0.3)
            assert s.controller.state is State.ARMED and s.sim.model.throttle_frac == 0.0
            await pilot.press("g")
            await pilot.pause(0.1)
            await pilot.press("y")
            assert await wait_for(pilot, lambda: s.controller.state is not State.ARMED, 5)
            t0 = time.monotonic()
            assert await wait_for(pilot, lambda: len(s.controller.points) >= 1, 60), s.controller.reason
            wall_to_point_s = time.monotonic() - t0
            await pilot.pause(0.4)  # one refresh
            text = screen_text(app)
            assert "points    1" in text or "points    2" in text, text
            # the efficiency plot shows the point's axis (secondary rpm)
            assert "efficiency vs secondary rpm" in text and "secondary rpm" in text
            await pilot.press("space")
            await pilot.pause(0.4)
            assert s.controller.state is State.ABORTED
            assert s.sim.actuators.is_safe
            text = screen_text(app)
            assert "ABORTED" in text and "rig SAFE" in text and "cause: estop" in text, text
            # Ctrl+C is an E-STOP too (not Textual's quit), and the app stays open after it.
            await pilot.press("ctrl+c")
            await pilot.pause(0.2)
            assert app.is_running and s.sim.actuators.is_safe
            # after an E-STOP nothing can move the rig: GO and jog are refused
            await pilot.press("g")
            await pilot.press("m")
            await pilot.pause(0.2)
            assert s.sim.model.throttle_frac == 0.0 and not s.manual
            await pilot.press("q")  # finished: quits without a question
            await pilot.pause(0.5)
        return wall_to_point_s

    wall_s = asyncio.run(scenario())
    assert wall_s < 60
    stop = [json.loads(line) for line in (tmp_path / "run" / "documents.jsonl").read_text().splitlines()
            if line.strip()]
    assert any(d.get("type") == "abort" and d.get("cause") == "estop" for d in stop)


def test_ui_live_quit_confirms_and_puts_rig_safe_first(tmp_path):
    async def scenario():
        app = LiveApp(LiveOptions(sim=True, speed=SPEED, seed=1, out_dir=tmp_path / "run"))
        async with app.run_test(size=SIZE) as pilot:
            assert await wait_for(pilot, lambda: app.session is not None
                                  and app.session.controller.state is State.ARMED, 30)
            s = app.session
            await pilot.press("g")
            await pilot.press("y")
            assert await wait_for(pilot, lambda: s.sim.model.throttle_frac == 1.0, 5)
            # manual mode: confirmation, then a jog moves the brake actuator
            await pilot.press("m")
            await pilot.pause(0.1)
            assert "MOVE THE BRAKE" in screen_text(app)
            await pilot.press("y")
            await pilot.pause(0.1)
            assert s.manual and s.controller.paused
            await pilot.press("right_square_bracket")
            await pilot.pause(0.05)
            moved = [h for h in s.sim.actuators.history if h[1] == "brake" and h[2] == 1]
            assert moved, s.sim.actuators.history[-5:]
            await pilot.pause(0.3)  # the jog ends by itself (0.2 s of rig time)
            assert s.sim.model.actuator_dir == 0
            await pilot.press("q")
            await pilot.pause(0.1)
            assert "safe state first" in screen_text(app)
            await pilot.press("y")
            await pilot.pause(1.0)
            return s

    s = asyncio.run(scenario())
    assert s.closed and s.sim.actuators.is_safe
    assert s.controller.state is State.ABORTED and s.controller.aborts[-1]["cause"] == "quit"
    assert (tmp_path / "run" / "documents.jsonl").read_text().count('"type": "stop"') == 1


def test_ui_live_snapshots_80x24(tmp_path):
    """Structural snapshot of each live view at 80x24: the labels an operator needs are all on screen."""

    async def scenario():
        shots = {}
        app = LiveApp(LiveOptions(sim=True, speed=SPEED, seed=2, out_dir=tmp_path / "run"))
        async with app.run_test(size=SIZE) as pilot:
            assert await wait_for(pilot, lambda: app.session is not None
                                  and app.session.controller.state is State.ARMED, 30)
            await pilot.pause(0.5)
            for key in ("1", "2", "3"):
                await pilot.press(key)
                await pilot.pause(0.3)
                shots[key] = screen_text(app)
            await pilot.press("g")
            await wait_for(pilot, lambda: "Start the test?" in screen_text(app), 10)
            shots["confirm"] = screen_text(app)
            await pilot.press("space")  # E-STOP from inside the dialog closes it
            # wait for the outcome, not a fixed pause: CI's 2 cores are busy
            await wait_for(pilot, lambda: "cause: estop" in screen_text(app)
                           and "Start the test?" not in screen_text(app), 10)
            shots["aborted"] = screen_text(app)
        return shots

    shots = asyncio.run(scenario())
    for name, text in shots.items():
        lines = text.splitlines()
        assert len(lines) == 24 and all(len(line) <= 80 for line in lines), name
        assert "E-STOP" in text, name
        assert "g GO  p pause  m manual  [ ] jog  1-3 plot  o overlay  q quit" in lines[-1], name
    for label in ("engine", "secondary", "ratio", "torque", "P out", "P engine", "effic.", "rotor", "points",
                  "link", "CRC/NACK", "lost", "ARMED", "SIM x8"):
        assert label in shots["1"], label
    assert "efficiency vs secondary rpm" in shots["1"]
    assert "shift curve" in shots["2"] and "ideal" in shots["2"] and "peak power" in shots["2"]
    assert "last 30 s" in shots["3"]
    assert "Start the test?" in shots["confirm"] and "y / Enter = yes" in shots["confirm"]
    assert "Start the test?" not in shots["aborted"] and "cause: estop" in shots["aborted"]
    assert "Ctrl+C)" in shots["aborted"]  # the cause's detail wraps at 80 columns, its end is not cut off


OVERLAY_SCRIPT = r"""
import asyncio, sys, time, json
from pathlib import Path
from dyno.ui.live_app import LiveApp
from dyno.ui.session import LiveOptions

async def main():
    out = {}
    app = LiveApp(LiveOptions(sim=True, speed=4, seed=0, out_dir=Path(sys.argv[1])))
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.pause(1.0)
        out["state"] = app.session.controller.state.value
        out["before"] = [m for m in ("dyno.model.bvp", "dyno.model.overlay", "dyno.model.solution")
                         if m in sys.modules]
        await pilot.press("o")
        t_end = time.monotonic() + 90
        from dyno.model.params import TABLE_6_1_POINT

        svc = lambda: app.overlay_service
        # a seed solved in the worker, or none needed: a solution stored by an earlier session is at hand
        stored = lambda: svc() is not None and not svc().entries and svc().nearest_distance(TABLE_6_1_POINT) <= 0.5
        solved = lambda: svc() is not None and any(e.result is not None for e in svc().entries.values())
        while time.monotonic() < t_end and not (solved() or stored()):
            await pilot.pause(0.2)
        out["seed"] = "stored" if stored() else [e.result.get("converged") for e in svc().entries.values() if e.result]
        out["after"] = [m for m in ("dyno.model.bvp", "dyno.model.overlay") if m in sys.modules]
        await pilot.press("space")
        await pilot.pause(0.2)
        await pilot.press("q")
    print(json.dumps(out))

asyncio.run(main())
"""


def test_ui_live_imports_belt_model_only_when_overlay_requested(tmp_path):
    # The simulated rig reads its belt-efficiency table from the belt model's cache
    # (built once per session by tests/conftest.py), which needs only the light
    # cache-key module; the *solver* waits for the first overlay request, and runs in another process.
    proc = subprocess.run([sys.executable, "-c", OVERLAY_SCRIPT, str(tmp_path / "run")], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert "dyno.model.bvp" not in out["before"] and "dyno.model.solution" not in out["before"], out
    # after it: the solver runs in the overlay's own process (its numerics never hold this interpreter's GIL,
    # which the poller and the controller need); here only the light overlay modules
    assert out["seed"] in ([True], "stored"), out
    assert "dyno.model.bvp" not in out["after"] and "dyno.model.overlay" in out["after"], out


# --- the pure parts ------------------------------------------------------------------------


def test_ui_live_model_pieces():
    assert temp_colour(25.0, 300.0) == ("#00c800", "")
    c, m = temp_colour(290.0, 300.0)
    assert c.startswith("#ff") and m == " HOT"
    assert temp_colour(301.0, 300.0)[1] == " OVER LIMIT"
    assert temp_colour(math.nan, 300.0)[1] == " (no reading)"
    assert fmt(math.nan) == "—" and fmt(12.345, ".1f", " N·m") == "12.3 N·m"
    r = RateMeter(window_s=1.0)
    r.update(0.0, 0)
    assert r.update(0.5, 75) == pytest.approx(150.0)
    pts = [{"rpm_primary": 3000.0, "ratio": 1.5, "power_in_w": 5000.0, "rpm_secondary": 2000.0},
           {"rpm_primary": math.nan, "ratio": 1.5, "power_in_w": 5000.0, "rpm_secondary": 2000.0}]
    (x, op), = overlay_inputs(pts)
    tq = 5000.0 / (3000 * 2 * math.pi / 60)
    assert x == 2000.0 and op.primary_speed_rpm == 3000.0 and op.primary_torque_nm == pytest.approx(tq)
    # the geometric ratio is the speed ratio less the belt's slip (Table 6.1 belt, 100 N slack)
    assert 1.5 * (1 - 0.01) < op.ratio < 1.5 and op.slack_tension_n == 100.0
    plan = scaled_plan(Plan(), 10.0)
    assert plan.warmup_s == pytest.approx(0.3) and plan.settle_mode == "fixed"
    assert plan.settle.fixed_settle_s == pytest.approx(0.4)
    assert scaled_plan(Plan(), 1.0) == Plan()
    from dyno.analysis.engine_map import load_engine_map
    from dyno.app import DEFAULT_ENGINE_MAP

    assert 2800 < ideal_engine_rpm(load_engine_map(DEFAULT_ENGINE_MAP)) < 4000


def test_ui_live_session_without_go_leaves_no_run_directory(tmp_path):
    """`dyno ui --sim` started and quit before GO: nothing ran, nothing left behind."""
    async def scenario():
        app = LiveApp(LiveOptions(sim=True, speed=SPEED, seed=1, out_dir=tmp_path / "run"))
        async with app.run_test(size=SIZE) as pilot:
            assert await wait_for(pilot, lambda: app.session is not None
                                  and app.session.controller.state is State.ARMED, 30)
            assert (tmp_path / "run" / "meta.json").exists()  # live, it has one to record an abort in
            await pilot.press("q")
            await wait_for(pilot, lambda: "Quit?" in screen_text(app), 10)
            await pilot.press("y")
            await pilot.pause(0.5)
        return app.session

    session = asyncio.run(scenario())
    assert session.run_dir_removed and not (tmp_path / "run").exists()
