"""Nothing a test starts outlives it: a copy of the suite's set-up (tests/conftest.py, screens.py, processes.py)
runs tests that fail mid-way with a rig running, and afterwards no process of that run is alive.

The inner run gets a suite mark of its own, so what is looked for is exactly what it started."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import uuid
from pathlib import Path

import pytest

from tests import processes

REPO = Path(__file__).resolve().parents[1]

FAILING_MID_UI = '''
import sys

def test_fails_with_the_ui_running(terminal, tmp_path):
    ui = terminal(f"{sys.executable} -m dyno ui --sim --speed 4 --out {tmp_path / 'run'} ; echo EXITED=$? ; sleep 30",
                  env={"HOME": str(tmp_path), "PYTHONPATH": "REPO"})
    ui.wait("ARMED", 150)
    ui.keys("g")
    ui.wait("Start the test?", 10)
    ui.keys("y")
    ui.wait("GO", 10)
    assert False, "deliberately, mid-test, the rig running"

def test_fails_with_a_headless_run_going(tmp_path):
    import os, subprocess
    subprocess.Popen([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--speed", "1",
                      "--out", str(tmp_path / "run")], env=dict(os.environ, PYTHONPATH="REPO"),
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    assert False, "deliberately, the run still going"
'''

DETACHED_STRAY = '''
import subprocess

def test_leaves_a_detached_process():
    # re-parented away from the test: only the session's end-of-run check can see it
    subprocess.run(["bash", "-c", "sleep 300 >/dev/null 2>&1 &"], check=True)
'''


def _copy_suite(tmp_path: Path, body: str) -> Path:
    root = tmp_path / "copy"
    (root / "tests").mkdir(parents=True)
    for name in ("conftest.py", "screens.py", "processes.py"):
        shutil.copy(REPO / "tests" / name, root / "tests" / name)
    (root / "tests" / "test_inner.py").write_text(textwrap.dedent(body).replace("REPO", str(REPO)))
    return root


def _run_copy(root: Path, mark: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env[processes.SUITE_MARK] = mark
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:randomly",
                           "--rootdir", str(root), "tests/test_inner.py"], cwd=root, env=env, capture_output=True,
                          text=True, timeout=600)


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_a_test_failing_mid_ui_leaves_no_process_behind(tmp_path):
    mark = uuid.uuid4().hex
    proc = _run_copy(_copy_suite(tmp_path, FAILING_MID_UI), mark)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 1 and "2 failed" in out, out[-4000:]
    assert "deliberately, mid-test, the rig running" in out and "deliberately, the run still going" in out
    assert "still alive at the end of the run" not in out, out[-4000:]  # the finalisers ended everything
    assert processes.marked(processes.SUITE_MARK, mark) == []


def test_the_end_of_run_check_fails_on_a_stray_and_ends_it(tmp_path):
    mark = uuid.uuid4().hex
    proc = _run_copy(_copy_suite(tmp_path, DETACHED_STRAY), mark)
    out = proc.stdout + proc.stderr
    assert "1 passed" in out and proc.returncode == 1, out[-4000:]  # the test passed; the run did not
    assert "still alive at the end of the run" in out and "sleep 300" in out, out[-4000:]
    assert processes.marked(processes.SUITE_MARK, mark) == []  # and the stray was ended
