"""`dyno calibrate --channel input|output` as real processes: the wizard in a real terminal (tmux) on the
simulated rig with the engine-side channel, judged against the simulator's true load cell; bad input one
line, exit 2, nothing written."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.bad_input import one_line_failures, snapshot


REPO = Path(__file__).resolve().parents[2]
INPUT_RIG = REPO / "hardware" / "rig-input-torque.toml"
SHIPPED_INPUT = REPO / "calibration" / "input_torque_calibration.csv"
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _dyno(*args, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          timeout=120, env=ENV, cwd=cwd)


def test_calibrate_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path):
    v1_rig = tmp_path / "rig-v1.toml"
    v1_rig.write_text(INPUT_RIG.read_text().replace('protocol = "v2"', 'protocol = "v1"', 1))
    bad_hist = tmp_path / "bad_input_history.csv"
    bad_hist.write_text(SHIPPED_INPUT.read_text().replace("586.5", "586,5", 1))  # a comma for a decimal point
    cases = [
        ("input channel, rig without it", ["calibrate", "--sim", "--channel", "input"], ["--channel", "rig.toml"]),
        ("input: fewer than 3 loads", ["calibrate", "--sim", "--channel", "input", "--rig", INPUT_RIG,
                                       "--masses", "2,4"], ["--masses", "at least 3"]),
        ("output: 2 distinct loads", ["calibrate", "--sim", "--masses", "5,5,10"], ["--masses", "at least 3"]),
        ("a mass that is not a number", ["calibrate", "--sim", "--masses", "5,ten,20"], ["--masses", "ten"]),
        ("repeats 0", ["calibrate", "--sim", "--repeats", "0"], ["--repeats"]),
        ("unknown channel", ["calibrate", "--sim", "--channel", "engine"], ["--channel"]),
        ("input channel on v1 firmware (the rig)", ["calibrate", "--channel", "input", "--rig", v1_rig],
         ["rig-v1.toml", "protocol"]),
        ("malformed input history", ["calibrate", "--sim", "--channel", "input", "--rig", INPUT_RIG,
                                     "--history", bad_hist], ["bad_input_history.csv", "line 3"]),
    ]
    before = snapshot(tmp_path)
    failures = one_line_failures(cases, lambda *argv: _dyno(*argv, cwd=tmp_path))
    assert not failures, "\n".join(failures)
    assert snapshot(tmp_path) == before  # nothing written (no runs/ either), the bad history byte-identical


def _env(home: Path) -> dict:
    return {"HOME": str(home), "PYTHONPATH": str(REPO)}  # the session's belt table and library: tests/screens.py


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_calibrate_input_channel_in_a_terminal_against_the_simulators_true_gain(tmp_path, terminal):
    """The whole procedure on the input channel, 3 repeats, keys in a real 80x24 terminal: the entry
    appended to the channel's history has the gain of the simulated cradle load cell (the physics' draw for
    the seed, computed here from the simulator's parameters, not read off the program), 1.8 % from the
    host's nominal 600; the spread across the repeats is shown; the old rows are untouched."""
    from dyno.analysis.calibration_history import load_history
    from dyno.sim.rig_params import RigParams
    from dyno.sim.world import input_channel_truth

    seed = 3
    true_gain, true_offset, _ = input_channel_truth(RigParams(), seed)
    hist = tmp_path / "input_history.csv"
    shutil.copy(SHIPPED_INPUT, hist)
    old = hist.read_bytes()
    cmd = (f"{sys.executable} -m dyno calibrate --sim --channel input --rig {INPUT_RIG} --repeats 3 --speed 10 "
           f"--seed {seed} --history {hist} ; echo EXITED=$? ; sleep 30")
    session = terminal(cmd, env=_env(tmp_path), cwd=tmp_path)
    try:
        screen = session.wait(["SETUP", "cradle arm", "2,4,6,8,10", "input"], 60)
        t_end = time.monotonic() + 240
        while time.monotonic() < t_end:
            screen = session.screen()
            if "REVIEW" in screen or "REJECTED" in screen:
                break
            if "COLLECTING" not in screen:
                session.keys("c")  # a spare press while collecting only says so
            time.sleep(0.3)
        screen = session.wait(["REVIEW", "slope", "reproducibility", "(3 repeats)", "history term"], 10)
        assert "meets the 0.4 %" in screen and "REFUSED" not in screen, screen
        assert all(len(line) <= 80 for line in screen.splitlines())
        session.keys("a")
        session.wait("Append this calibration", 10)
        session.keys("y")
        session.wait("appended to", 10)
        session.keys("q")
        session.wait("EXITED=0", 20)
    finally:
        session.close()
    assert hist.read_bytes().startswith(old)
    entries = load_history(hist)
    assert len(entries) == 5
    e = entries[-1]
    # 0.15 %: 4x the rms error of 3-repeat calibrations over 8 seeds (0.037 %; the terminal's timing moves
    # which conversions a step keeps), a tenth of the 1.6 % the seeds' gains scatter
    assert abs(e.slope_counts_per_nm / true_gain - 1.0) < 0.0015, (e.slope_counts_per_nm, true_gain)
    assert abs(e.intercept_counts - true_offset) < 10.0, (e.intercept_counts, true_offset)
    assert abs(true_gain / 600.0 - 1.0) > 0.01  # the host's nominal: echoing it would fail the line above
    assert e.gear_ratio_brake_per_secondary == 1.0 and e.lever_arm_m == 0.2 and e.n_samples == 27 * 500
    assert "--channel input" in e.note and "3 repeats, reproducibility" in e.note
    assert not (tmp_path / "runs").exists()  # --history given: nothing else written


def test_a_runs_zero_checks_see_the_input_channels_own_drift(tmp_path):
    """The zero checks of a run cover both channels, each from its own converter: a simulated cradle load cell
    whose zero creeps (0.6 N·m/min, the brake-side bridge left still) is flagged in ``torque_zero_input`` by
    the amount the physics drifted between the two windows, and ``torque_zero`` is not."""
    import dataclasses

    from dyno.session.root import RunSpec, run_test
    from dyno.sim.rig_params import RigParams
    from tests.e2e.conftest import QUICK_PLAN

    rate = 0.6  # crank N m per minute
    captured = {}
    r = run_test(RunSpec(sim=True, seed=5, out_dir=tmp_path / "run", rig_path=INPUT_RIG, plan=QUICK_PLAN,
                            sim_params=dataclasses.replace(RigParams(), input_zero_drift_nm_per_min=rate),
                            setup=lambda ctx: captured.setdefault("ctx", ctx)))
    zi, zo = r["torque_zero_input"], r["torque_zero"]
    world = captured["ctx"].sim.model.world
    b, a = zi["before"], zi["after"]
    assert math.isfinite(b["torque_nm"]) and math.isfinite(a["torque_nm"]), zi
    # the physics: counts creep at rate * true gain / 60 per second; the host reads them with its 600
    span_s = (zo["after"]["t_mid_s"] - zo["before"]["t_mid_s"])
    expected = rate / 60.0 * span_s * world.input_gain_counts_per_nm / 600.0
    assert zi["drift_nm"] == pytest.approx(expected, abs=0.05 + 2 * zi["drift_ci95_nm"]), (zi, expected)
    assert zi["flagged"] and "drifted" in zi["note"]
    assert not zo["flagged"] and abs(zo["drift_nm"]) <= zo["drift_ci95_nm"] + 0.05, zo
    # recorded with the run (documents.jsonl), so the report shows it
    import json

    from dyno.report.writer import write_report

    docs = [json.loads(line) for line in (tmp_path / "run" / "documents.jsonl").read_text().splitlines()]
    (logged,) = [d for d in docs if d.get("type") == "torque_zero_input"]
    assert logged["drift_nm"] == pytest.approx(zi["drift_nm"]) and logged["flagged"]
    html = write_report(tmp_path / "run").read_text()
    assert "Torque zero, input channel" in html and f"{zi['drift_nm']:+.3f}" in html
