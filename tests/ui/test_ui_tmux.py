"""The real `dyno ui --sim` in a real terminal (tmux, 80x24): keys in, screen out."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.screens import Terminal

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")


# (ARMED within 120 s: a UI start-up took over 60 s once with a bench on the other test worker)
def _env(home: Path) -> dict:
    """A terminal's environment: a fresh HOME (the belt-model table and the run library stay the session's:
    tests/screens.py)."""
    return {"HOME": str(home), "PYTHONPATH": str(Path(__file__).resolve().parents[2])}


def _go(session: Terminal) -> None:
    """Wait for ARMED, press g, confirm: the test runs."""
    session.wait("ARMED", 120)
    session.keys("g")
    session.wait("Start the test?", 10)
    session.keys("y")
    session.wait("GO: full throttle", 10)


def test_ui_tmux_dyno_ui_sim(tmp_path, terminal):
    run_dir = tmp_path / "run"
    cmd = (f"{sys.executable} -m dyno ui --sim --speed 4 --out {run_dir} ; echo EXITED=$? ; sleep 30")
    session = terminal(cmd, env=_env(tmp_path))
    try:
        screen = session.wait("ARMED", 120)
        assert "E-STOP" in screen and "g GO" in screen and "engine" in screen
        session.keys("g")
        session.wait("Start the test?", 10)
        session.keys("y")
        screen = session.wait("GO: full throttle", 10)
        session.keys("C-c")  # E-STOP, not quit
        screen = session.wait("cause: estop", 10)
        assert "ABORTED" in screen and "rig SAFE" in screen
        assert "EXITED" not in screen  # Ctrl+C did not kill the app
        session.keys("q")
        screen = session.wait("EXITED=0", 20)
    finally:
        session.close()
    docs = (run_dir / "documents.jsonl").read_text()
    assert '"cause": "estop"' in docs and '"type": "stop"' in docs


def test_ui_tmux_sighup_mid_test_leaves_abort_record(tmp_path, terminal):
    """The terminal (or the SSH link) goes away mid-test: SIGHUP -> safe state, abort + stop record."""
    run_dir = tmp_path / "run"
    cmd = f"{sys.executable} -m dyno ui --sim --speed 4 --out {run_dir}"
    session = terminal(cmd, env=_env(tmp_path))
    try:
        _go(session)
    finally:
        # closing the terminal sends SIGHUP to the program in it
        session.close()
    docs_path = run_dir / "documents.jsonl"
    t_end = time.monotonic() + 20
    while time.monotonic() < t_end and '"type": "stop"' not in docs_path.read_text():
        time.sleep(0.2)
    docs = docs_path.read_text()
    assert '"cause": "signal"' in docs and "SIGHUP" in docs
    assert '"type": "stop"' in docs and '"exit_status": "abort"' in docs


def test_ui_tmux_space_estops_with_the_go_dialog_open(tmp_path, terminal):
    """E-STOP on the space bar while a modal has the focus: the modal closes, the rig is safe."""
    run_dir = tmp_path / "run"
    session = terminal(f"{sys.executable} -m dyno ui --sim --speed 4 --out {run_dir} ; echo EXITED=$? ; sleep 30",
           env=_env(tmp_path))
    try:
        session.wait("ARMED", 120)
        session.keys("g")
        session.wait("Start the test?", 10)
        session.keys("Space")
        screen = session.wait("cause: estop", 10)
        assert "ABORTED" in screen and "rig SAFE" in screen and "Start the test?" not in screen
        session.keys("q")
        session.wait("EXITED=", 20)
    finally:
        session.close()


def test_calibrate_tmux_space_estops_with_a_text_field_focused(tmp_path, terminal):
    """The wizard starts with the radius field focused: space is E-STOP there too, never a typed blank."""
    hist = tmp_path / "h.csv"
    session = terminal(f"{sys.executable} -m dyno calibrate --sim --history {hist} ; echo EXITED=$? ; sleep 30",
           env=_env(tmp_path), size=(100, 30))
    try:
        screen = session.wait("SETUP", 60)
        assert "0.15" in screen  # the focused field's default
        session.keys("Space")
        screen = session.wait("ABORTED (estop)", 10)
        assert "rig SAFE" in screen and "nothing written" in screen
        assert "REJECTED" in screen  # the calibration ended; the key was not typed into the field
        session.keys("q")
        screen = session.wait("EXITED=", 20)
        assert "EXITED=0" in screen
    finally:
        session.close()
    assert not hist.exists()


def test_ui_tmux_kill_int_mid_test_leaves_abort_record(tmp_path, terminal):
    """SIGINT from outside (kill -INT, not the Ctrl+C key): safe state, abort + stop record, exit 130."""
    import os
    import signal

    run_dir = tmp_path / "run"
    marker = tmp_path / "rc"
    session = terminal(f"{sys.executable} -m dyno ui --sim --speed 4 --out {run_dir} ; echo $? > {marker} ; sleep 30",
           env=_env(tmp_path))
    try:
        _go(session)
        pid = int(subprocess.run(["pgrep", "-f", f"^{sys.executable} -m dyno ui --sim --speed 4 --out {run_dir}"],
                                 capture_output=True, text=True, timeout=20).stdout.split()[0])
        os.kill(pid, signal.SIGINT)
        docs_path = run_dir / "documents.jsonl"
        t_end = time.monotonic() + 20
        while time.monotonic() < t_end and not marker.exists():
            time.sleep(0.2)
        assert marker.exists() and marker.read_text().strip() == "130"  # 128 + SIGINT
    finally:
        session.close()
    docs = docs_path.read_text()
    assert '"cause": "signal"' in docs and "SIGINT" in docs and '"type": "stop"' in docs


def test_calibrate_tmux_sigterm_aborts_and_writes_nothing(tmp_path, terminal):
    import os
    import signal

    hist = tmp_path / "h.csv"
    marker = tmp_path / "rc"
    session = terminal(f"{sys.executable} -m dyno calibrate --sim --history {hist} ; echo $? > {marker} ; sleep 30",
           env=_env(tmp_path), size=(100, 30))
    try:
        session.wait("SETUP", 60)
        # the python process itself, not the shell tmux runs it in
        pid = int(subprocess.run(["pgrep", "-f", f"^{sys.executable} -m dyno calibrate --sim --history {hist}"],
                                 capture_output=True, text=True, timeout=20).stdout.split()[0])
        os.kill(pid, signal.SIGTERM)
        t_end = time.monotonic() + 20
        while time.monotonic() < t_end and not marker.exists():
            time.sleep(0.2)
        assert marker.exists() and marker.read_text().strip() == "143"
    finally:
        session.close()
    assert not hist.exists()


def test_ui_tmux_rearm_after_estop_starts_a_second_run(tmp_path, terminal):
    """The real `dyno ui --sim`: GO, E-STOP, `r` (once the engine has stopped), confirm: ARMED again in a new
    run directory; a second test there; at exit both runs have their record, report.html and path printed."""
    run_dir = tmp_path / "run"
    session = terminal(f"{sys.executable} -m dyno ui --sim --speed 8 --out {run_dir} ; echo EXITED=$? ; sleep 60",
           env=_env(tmp_path))
    try:
        _go(session)
        session.keys("Space")
        screen = session.wait("cause: estop", 10)
        assert "r re-arm" in screen.splitlines()[-1] or "r re-arm" in screen
        # `r` is refused while the engine still turns; ask until it is accepted (a condition, not a sleep)
        t_end = time.monotonic() + 60
        while time.monotonic() < t_end:
            session.keys("r")
            screen = session.screen()
            if "Acknowledge" in screen:
                break
            time.sleep(0.5)
        screen = session.wait("Acknowledge: ABORTED (estop", 5)
        session.keys("y")
        screen = session.wait("re-armed: new run", 10)
        assert "run-2" in screen.splitlines()[0]  # the title names the run being written
        _go(session)  # ARMED again (the simulated operator restarts the engine), then a second GO
        session.keys("Space")
        session.wait("cause: estop", 10)
        session.keys("q")
        screen = session.wait("EXITED=0", 120)
    finally:
        session.close()
    run2 = tmp_path / "run-2"
    for d in (run_dir, run2):
        docs = (d / "documents.jsonl").read_text()
        assert '"cause": "estop"' in docs and '"type": "stop"' in docs, d
        assert (d / "report.html").is_file(), d
    assert f"run: {run_dir}" in screen.replace("\n", "") and f"run: {run2}" in screen.replace("\n", "")


def test_ui_tmux_coast_down_shows_its_results(tmp_path, terminal):
    """`dyno ui --sim --plan coast-down` in a real terminal: when the plan ends, its loss fit is on screen
    (the run's characterisation document, units labelled); at exit the report has it too."""
    import json

    run_dir = tmp_path / "run"
    session = terminal(f"{sys.executable} -m dyno ui --sim --speed 8 --plan coast-down --out {run_dir} ; "
                    "echo EXITED=$? ; sleep 30", env=_env(tmp_path))
    try:
        session.wait("ARMED", 120)
        session.keys("g")
        session.wait("ENGINE IS CUT", 10)  # the dialog says what this plan moves
        session.keys("y")
        session.wait("GO: full throttle, then engine cut", 10)
        screen = session.wait("COAST-DOWN: driven-side loss", 90)
        assert "DONE" in screen and "T = a + b·ω + c·ω² (ω in rad/s)" in screen and "4 results" in screen
        # the numbers are the run's stored characterisation (written at DONE), formatted
        docs = [json.loads(line) for line in (run_dir / "documents.jsonl").read_text().splitlines()]
        (c,) = [d for d in docs if d.get("type") == "characterisation"]
        fit = c["loss_fit"]
        assert f"a = {fit['coefficients']['a_nm']:.4f} N·m" in screen, screen
        assert f"over {fit['rpm_min']:.0f}–{fit['rpm_max']:.0f} rpm" in screen, screen
        session.keys("q")
        session.wait("EXITED=0", 30)
    finally:
        session.close()
    report = (run_dir / "report.html").read_text()
    assert "<h2>Characterisation</h2>" in report and f"{fit['coefficients']['a_nm']:.4f}" in report
