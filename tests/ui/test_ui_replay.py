"""Replay viewer: browse, re-process, overlay two runs, export CSV and PNG; entry points without the belt solver."""

from __future__ import annotations

import asyncio
import re
import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from dyno.ui.replay_app import ReplayApp
from dyno.ui.replay_model import ReplaySet, efficiency_series, export_png, point_streams
from tests.screens import screen_text

SIZE = (80, 24)
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    """Two short simulated runs of one rig (3 points each, different seeds), as fast as the sim goes."""
    from dyno.session.root import RunSpec, run_test
    from dyno.control.api import TestPlan
    from dyno.sim.rig_params import RigParams

    root = tmp_path_factory.mktemp("runs")
    out = []
    for seed in (0, 1):
        d = root / f"run{seed}"
        # one rig measured twice (world_seed: its engine, sensor and day shared; dyno.sim.world), new noise
        r = run_test(RunSpec(sim=True, seed=seed, out_dir=d, plan=replace(TestPlan(), max_points=3),
                                sim_params=RigParams(world_seed=0)))
        assert r["state"] == "done" and len(r["points"]) == 3
        out.append(d)
    return out


def test_ui_replay_model_reprocess_and_png(two_runs, tmp_path):
    rs = ReplaySet.load(two_runs)
    assert [len(r.points) for r in rs.runs] == [3, 3]
    x, y, e = efficiency_series(rs.runs[0].points)
    assert len(x) == 3 and all(60 < v < 100 for v in y)
    d = point_streams(rs.runs[0].run, rs.runs[0].points[0])
    assert d["adc_counts"] and d["primary_rpm"] and d["window_s"] > 2.9
    # Re-process with a calibration whose slope is 10 % higher: torque (and efficiency) 10 % lower.
    from dyno.analysis.calibration_history import CalibrationEntry, append_entry

    cal = rs.runs[0].result["calibration"]
    hist = tmp_path / "cal.csv"
    append_entry(hist, CalibrationEntry.from_dict({**cal, "slope_counts_per_nm": cal["slope_counts_per_nm"] * 1.1,
                                                   "date": "2099-01-01"}))
    before = rs.runs[0].points[1]["torque_secondary_nm"]
    rs.reprocess(0, calibration_path=hist)
    after = rs.runs[0].points[1]["torque_secondary_nm"]
    assert after == pytest.approx(before / 1.1, rel=0.02)
    assert "cal cal.csv" in rs.runs[0].label
    png = export_png(rs, tmp_path / "out" / "replay.png", 3340.0)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_ui_replay_app_browse_overlay_export(two_runs, tmp_path):
    async def scenario():
        shots = {}
        app = ReplayApp(two_runs, png_path=tmp_path / "r.png")
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause(0.5)
            shots["eff"] = screen_text(app)
            await pilot.press("2")
            await pilot.pause(0.2)
            shots["shift"] = screen_text(app)
            await pilot.press("down", "3")
            await pilot.pause(0.3)
            shots["raw"] = screen_text(app)
            await pilot.press("n")
            await pilot.pause(0.2)
            shots["run2"] = screen_text(app)
            await pilot.press("4")
            for _ in range(25):  # the comparison is computed on the UI thread: wait for the redraw
                await pilot.pause(0.2)
                shots["diff"] = screen_text(app)
                if "vs run 1" in shots["diff"]:
                    break
            await pilot.press("x")
            await pilot.pause(0.5)
            await pilot.press("s")
            for _ in range(50):
                await pilot.pause(0.2)
                if (tmp_path / "r.png").exists():
                    break
            await pilot.press("e")
            await pilot.pause(0.2)
            shots["ask"] = screen_text(app)
            await pilot.press("escape")
            await pilot.press("ctrl+c")
            await pilot.pause(0.2)
            shots["estop"] = screen_text(app)
            running = app.is_running
            await pilot.press("q")
        return shots, running

    shots, running = asyncio.run(scenario())
    for name, text in shots.items():
        lines = text.splitlines()
        assert len(lines) == 24 and all(len(line) <= 80 for line in lines), name
        assert "E-STOP" in lines[-1] and "n run  1-4 plot  c cal  e map  x CSV  s PNG  q quit" in lines[-1], name
    assert "run 1/2: run0" in shots["eff"] and "efficiency vs secondary rpm" in shots["eff"]
    assert "T N·m" in shots["eff"] and "eff %" in shots["eff"]
    assert "shift curve" in shots["shift"] and "run0" in shots["shift"] and "run1" in shots["shift"]
    assert "point 1: rpm (left), ADC (right)" in shots["raw"]
    assert "run 2/2: run1" in shots["run2"]
    # same tune, another seed: no difference claimed at the 2-3 common grid speeds (a 95 % test on 3 points)
    assert re.search(r"Δeff % vs run 1: 0/[2-6] sig\. 95 %", shots["diff"]), shots["diff"]
    assert "tune: same as run 1" in shots["diff"]
    assert "which engine map file?" in shots["ask"]
    assert running and "no rig is attached" in shots["estop"]
    assert (two_runs[1] / "export" / "points.csv").exists() and (two_runs[1] / "export" / "adc.csv").exists()
    assert (tmp_path / "r.png").read_bytes()[:4] == b"\x89PNG"


ENTRY_SCRIPT = r"""
import asyncio, json, sys
from pathlib import Path
which, arg = sys.argv[1], sys.argv[2]

async def main():
    if which == "replay":
        from dyno.ui.replay_app import ReplayApp
        app = ReplayApp([Path(arg)])
    else:
        from dyno.ui.calibrate_app import CalibrateApp, CalibrateOptions
        app = CalibrateApp(CalibrateOptions(sim=True, n_samples=20, settle_samples=5, history_path=Path(arg)))
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.pause(0.5)
        await pilot.press("ctrl+q")

import dyno.cli
from dyno.cli import COMMANDS
import importlib
importlib.import_module(COMMANDS[which][0])  # the command module, as `dyno <which>` imports it
asyncio.run(main())
print(json.dumps(sorted(m for m in sys.modules if m.startswith("dyno.model"))))
"""


@pytest.mark.parametrize("which", ["replay", "calibrate"])
def test_ui_entry_points_start_without_belt_solver(which, two_runs, tmp_path):
    arg = str(two_runs[0]) if which == "replay" else str(tmp_path / "h.csv")
    proc = subprocess.run([sys.executable, "-c", ENTRY_SCRIPT, which, arg], capture_output=True, text=True,
                          timeout=120, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-2000:]
    loaded = json.loads(proc.stdout.strip().splitlines()[-1])
    assert "dyno.model.bvp" not in loaded, loaded
