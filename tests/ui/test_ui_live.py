"""Live run screen driven headless by Textual's pilot on the simulated rig (paced faster than real time)."""

from __future__ import annotations

import asyncio
import json
import math
import re
import subprocess
import sys

import pytest

from dyno.control.api import State
from dyno.ui.live_app import LiveApp
from dyno.model.overlay_inputs import overlay_inputs
from dyno.analysis.live import RateMeter, ideal_engine_rpm
from dyno.ui.live_model import fmt, temp_colour
from dyno.ui.session import LiveOptions
from tests.rig_files import rig_without_run_enable
from tests.screens import screen_text, wait_for

SPEED = 8.0  # 8x real time: a first point within ~10 s of wall time on a loaded 2-core machine
SIZE = (80, 24)


def armed_why(app) -> str:
    """Where the controller is instead of ARMED (for a failure message)."""
    s = app.session
    if s is None:
        return "no session"
    c = s.controller
    return f"state {c.state.value} ({c.reason}); aborts {c.aborts}; sim t {s.sim.model.t_s:.1f} s"


def test_ui_live_go_points_estop(tmp_path):
    """Start a simulated run, GO (confirmed), see points appear on screen, E-STOP: safe state and cause shown."""

    async def scenario():
        # (the device reset below is survived by the link only with the Nano's run-enable out of the kill chain:
        # wired, a reset cuts the engine, tests/e2e/test_e2e_drills.py)
        app = LiveApp(LiveOptions(sim=True, speed=SPEED, seed=0, out_dir=tmp_path / "run",
                                  rig_path=rig_without_run_enable(tmp_path)))
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
            # MEASURE shows its clock against the cap (rig seconds), not the minimum average
            assert await wait_for(pilot, lambda: "MEASURE  " in screen_text(app), 60), s.controller.reason
            text = screen_text(app)
            assert re.search(r"MEASURE  \d+ / 24 s \(≥ 3 s, until s.e. ≤ 0.12 pp\)  │ point 0  ETA —", text), text
            # a device reset inside the window: the controller discards it and measures again; the screen says why.
            # (A window lasts >= 0.4 s of wall time at 8x; if it closed before the reset was seen, the next one.)
            for _ in range(5):
                assert await wait_for(pilot, lambda: s.controller.state is State.MEASURE, 60), s.controller.reason
                s.sim.bus.schedule_reset(s.sim_now())
                assert await wait_for(pilot, lambda: s.controller.discards or s.controller.state is not State.MEASURE,
                                      30), s.controller.reason
                if s.controller.discards:
                    break
            assert s.controller.discards, s.controller.reason
            assert await wait_for(pilot, lambda: "window discarded" in screen_text(app), 5), screen_text(app)
            text = screen_text(app)
            assert re.search(r"last: point \d+, try 1: device reset", text), text
            assert "discarded 1 window" in text, text
            assert await wait_for(pilot, lambda: len(s.controller.points) >= 1, 60), s.controller.reason
            assert await wait_for(pilot, lambda: "points    1" in screen_text(app) or "points    2" in screen_text(app),
                                  5), screen_text(app)
            # the efficiency plot shows the point's axis (secondary rpm)
            text = screen_text(app)
            assert "efficiency vs secondary rpm" in text and "secondary rpm" in text
            # from the second point on, the test's ETA (the headless progress line's estimate)
            assert await wait_for(pilot, lambda: len(s.controller.points) >= 2, 60), s.controller.reason
            assert await wait_for(pilot, lambda: "/~" in screen_text(app), 5), screen_text(app)
            text = screen_text(app)
            assert "ETA —" not in text and re.search(r"point [2-9]/~\d+  ETA \d", text), text
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

    asyncio.run(scenario())
    stop = [json.loads(line) for line in (tmp_path / "run" / "documents.jsonl").read_text().splitlines()
            if line.strip()]
    assert any(d.get("type") == "abort" and d.get("cause") == "estop" for d in stop)


def test_ui_live_quit_confirms_and_puts_rig_safe_first(tmp_path):
    async def scenario():
        app = LiveApp(LiveOptions(sim=True, speed=SPEED, seed=1, out_dir=tmp_path / "run"))
        async with app.run_test(size=SIZE) as pilot:
            assert await wait_for(pilot, lambda: app.session is not None
                                  and app.session.controller.state is State.ARMED, 30), armed_why(app)
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
                                  and app.session.controller.state is State.ARMED, 30), armed_why(app)
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
            why = [a for a in app.session.controller.aborts if a["cause"] != "estop"]
        return shots, why

    shots, why = asyncio.run(scenario())
    assert not why, why  # nothing but the E-STOP ended the session
    for name, text in shots.items():
        lines = text.splitlines()
        assert len(lines) == 24 and all(len(line) <= 80 for line in lines), name
        assert "E-STOP" in text, name
        if name == "aborted":  # after the test: re-arm instead of the test's keys
            assert "r re-arm (new run)  1-3 plot  4 results  o overlay  q quit" in lines[-1], name
        else:
            assert "g GO  p pause  m manual  [ ] jog  1-3 plot  o overlay  q quit" in lines[-1], name
    for label in ("engine", "secondary", "ratio", "torque", "P out", "P engine", "effic.", "rotor", "points",
                  "link", "CRC/NACK", "lost", "discarded", "ARMED", "SIM x8", "run "):
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
        out["after"] = [m for m in ("dyno.model.bvp", "dyno.model.overlay_service") if m in sys.modules]
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
    assert "dyno.model.bvp" not in out["after"] and "dyno.model.overlay_service" in out["after"], out


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
    from dyno.analysis.engine_map import load_engine_map
    from dyno.resources import DEFAULT_ENGINE_MAP

    assert 2800 < ideal_engine_rpm(load_engine_map(DEFAULT_ENGINE_MAP)) < 4000


def test_ui_live_session_without_go_leaves_no_run_directory(tmp_path):
    """`dyno ui --sim` started and quit before GO: nothing ran, nothing left behind."""
    async def scenario():
        app = LiveApp(LiveOptions(sim=True, speed=SPEED, seed=1, out_dir=tmp_path / "run"))
        async with app.run_test(size=SIZE) as pilot:
            assert await wait_for(pilot, lambda: app.session is not None
                                  and app.session.controller.state is State.ARMED, 30), armed_why(app)
            assert (tmp_path / "run" / "meta.json").exists()  # live, it has one to record an abort in
            await pilot.press("q")
            await wait_for(pilot, lambda: "Quit?" in screen_text(app), 10)
            await pilot.press("y")
            await pilot.pause(0.5)
        return app.session

    session = asyncio.run(scenario())
    assert session.run_dir_removed and not (tmp_path / "run").exists()


def test_ui_live_rearm_after_estop_starts_a_new_run(tmp_path):
    """E-STOP, then `r`: refused while the rig is not safe, asks, then a new run directory; the aborted run
    keeps its abort record and gets its report.html; the new run arms without moving anything; GO works."""
    from dyno.protocol import v1

    from dyno.rig.config import DEFAULT_RIG_PATH

    rig = tmp_path / "rig-bme280.toml"  # (a BME280 fitted: each run reads its own air)
    rig.write_text(DEFAULT_RIG_PATH.read_text())  # (the shipped rig file fits one)

    async def scenario():
        app = LiveApp(LiveOptions(sim=True, speed=SPEED, seed=3, out_dir=tmp_path / "run", rig_path=rig))
        async with app.run_test(size=SIZE) as pilot:
            assert await wait_for(pilot, lambda: app.session is not None
                                  and app.session.controller.state is State.ARMED, 30), armed_why(app)
            s = app.session
            first = s.controller
            await pilot.press("r")  # nothing has ended: nothing to re-arm
            assert await wait_for(pilot, lambda: "re-arm only after a test has ended" in screen_text(app), 5)
            await pilot.press("g")
            await pilot.press("y")
            assert await wait_for(pilot, lambda: s.sim.model.throttle_frac == 1.0, 10)
            await pilot.press("space")
            assert await wait_for(pilot, lambda: "r re-arm (new run)" in screen_text(app), 5), screen_text(app)
            # refused while the engine still turns (it was at full throttle a moment ago)
            rp = s.poller.rpm(v1.CH_PRIMARY)
            why = s.rearm_refusal()
            if rp > first.plan.engine_running_rpm:
                assert "engine still turns" in why, why
            # refused with an output not in its safe state (a fault injected on the simulated rig)
            # (the wiring: the latched driver refuses it, so the fault is a servo driven past the driver)
            s.sim.actuators.wiring.throttle(0.3)
            assert "not in its safe state" in s.rearm_refusal()
            await pilot.press("r")
            assert await wait_for(pilot, lambda: "not in its safe state" in screen_text(app), 5), screen_text(app)
            assert "Acknowledge" not in screen_text(app) and s.controller is first
            s.sim.actuators.safe_state()
            # once the engine has stopped: asks, `n` changes nothing
            assert await wait_for(pilot, lambda: s.rearm_refusal() is None, 60), s.rearm_refusal()
            # at rest after the test: the poller drops from the full rate to the idle rate (the screen left up)
            idle_period_s = 1 / first.limits.armed_poll_hz
            assert await wait_for(pilot, lambda: s.poller.poll_period_s == pytest.approx(idle_period_s), 5)
            await pilot.press("r")
            assert await wait_for(pilot, lambda: "Acknowledge: ABORTED (estop" in screen_text(app), 5)
            await pilot.press("n")
            assert await wait_for(pilot, lambda: "re-arm cancelled" in screen_text(app), 5)
            assert s.controller is first and not (tmp_path / "run-2").exists()
            await pilot.press("r")
            assert await wait_for(pilot, lambda: "Acknowledge" in screen_text(app), 5)
            await pilot.press("y")
            assert await wait_for(pilot, lambda: s.controller is not first, 5), screen_text(app)
            # the new controller keeps the paced clock (x SPEED): without it its runners timed in host seconds
            assert s.controller.time_scale == first.time_scale == pytest.approx(1 / SPEED)
            assert (tmp_path / "run-2" / "meta.json").is_file() and s.run_dirs == [tmp_path / "run", tmp_path / "run-2"]
            # the air: read for the first run, after it (its `ambient` document), and again for the new one
            chip = s.sim.bus.devices[0x76]
            assert chip.conversions == 3
            meta2 = json.loads((tmp_path / "run-2" / "meta.json").read_text())
            assert meta2["ambient"]["source"] == "sensor" and meta2["ambient"]["j1349_factor"] > 0.8
            docs1 = [json.loads(x) for x in (tmp_path / "run" / "documents.jsonl").read_text().splitlines() if x]
            assert [d for d in docs1 if d.get("type") == "ambient"][0]["end"]["source"] == "sensor"
            # armed again: the engine restarted by the (simulated) operator, nothing moved by the software
            assert await wait_for(pilot, lambda: s.controller.state is State.ARMED, 30), s.controller.reason
            assert await wait_for(pilot, lambda: "g GO  p pause" in screen_text(app) and "run-2" in screen_text(app)
                                  and "ARMED" in screen_text(app), 5), screen_text(app)
            assert s.sim.model.throttle_frac == 0.0 and s.sim.model.actuator_dir != 1
            assert "points    0" in screen_text(app)
            # the aborted run's report is written in the background
            assert await wait_for(pilot, lambda: (tmp_path / "run" / "report.html").is_file(), 90)
            # and the new run is a test like the first: GO, E-STOP
            await pilot.press("g")
            await pilot.press("y")
            assert await wait_for(pilot, lambda: s.sim.model.throttle_frac == 1.0, 10)
            assert s.poller.poll_period_s == pytest.approx(1 / s.poller.full_poll_hz)  # a test: the full rate again
            await pilot.press("space")
            assert await wait_for(pilot, lambda: "cause: estop" in screen_text(app), 5)
            # after a software fault there is no re-arm: a fresh start of dyno
            s.controller.aborts.append({"cause": "watchdog", "detail": "drill"})
            assert "not re-armed after watchdog" in s.rearm_refusal()
            s.controller.aborts.pop()
            await pilot.press("q")
            await pilot.pause(0.5)
        return app.session

    session = asyncio.run(scenario())
    docs = [json.loads(line) for line in (tmp_path / "run" / "documents.jsonl").read_text().splitlines()]
    assert [d["cause"] for d in docs if d["type"] == "abort"] == ["estop"]
    assert docs[-1]["type"] == "stop" and docs[-1]["exit_status"] == "abort"
    docs2 = [json.loads(line) for line in (tmp_path / "run-2" / "documents.jsonl").read_text().splitlines()]
    assert [d["cause"] for d in docs2 if d["type"] == "abort"] == ["estop"]
    assert docs2[-1]["type"] == "stop"
    meta2 = json.loads((tmp_path / "run-2" / "meta.json").read_text())
    assert meta2["rearmed_after"] == str(tmp_path / "run") and meta2["mode"] == "sim"
    assert (tmp_path / "run-2" / "calibration.json").is_file() and (tmp_path / "run-2" / "engine_map.csv").is_file()
    assert session.closed and session.sim.actuators.is_safe
