"""Every entry point ends, safe state first, when its terminal goes (a closed tmux pane, a lost SSH session),
however it was started and at any moment, start-up included (issue 23).

Each case starts the command from a shell in a tmux pane, walks it to one of its screens (or closes the pane
0.5 s after launch, while it is still importing and building), closes the pane, and times the process out.
Then it reads what the command recorded: the run's documents (an abort for SIGHUP, the `safety` document's
physical outputs: throttle idle, ignition killed, pads off the rotor) and the run library's index.
"""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from tests.fw_build import sim_elf
from tests.screens import Terminal, pids_matching, seconds_until_gone

REPO = Path(__file__).resolve().parents[2]
ELF = REPO / "firmware" / "build" / "dyno_nano.elf"
GONE_BOUND_S = 3.0  # target 1 s; typical 0.1-0.8 s (docs/safety.md); 2.0 s seen with two workers and a bench
STARTUP_S = 0.5  # the pane closes this long after launch: still importing, before the first screen

UI = ["ui", "--sim", "--speed", "2"]  # (x2: the screens come twice as fast, the engine stops sooner)
CAL = ["calibrate", "--sim", "--samples", "40", "--settle-samples", "10", "--speed", "4"]
RUN = ["run", "--sim", "--headless", "--plan", "engagement"]
GO = [("wait", "ARMED"), ("keys", "g"), ("wait", "Start the test?"), ("keys", "y"), ("wait", "WARMUP")]
ESTOP = GO + [("keys", "Space"), ("wait", "cause: estop")]
REARM = ESTOP + [("until", "r", "Acknowledge", 60)]  # `r` is refused while the engine still turns

# (id, command, steps to the screen; None: close at start-up)
CASES = [
    ("ui-start-up", UI, None),
    ("ui-armed", UI, [("wait", "ARMED")]),
    ("ui-go-confirm", UI, [("wait", "ARMED"), ("keys", "g"), ("wait", "Start the test?")]),
    ("ui-test-running", UI, GO + [("sleep", 3.0)]),  # past the warm-up: the brake stepping, to be released
    ("ui-aborted", UI, ESTOP),
    ("ui-re-arm-confirm", UI, REARM),
    ("ui-re-armed", UI, REARM + [("keys", "y"), ("wait", "re-armed: new run")]),
    ("ui-quit-confirm", UI, [("wait", "ARMED"), ("keys", "q"), ("wait", "Quit?")]),
    ("calibrate-start-up", CAL, None),
    ("calibrate-setup", CAL, [("wait", "Enter the rope radius")]),
    ("calibrate-tare", CAL, [("wait", "Enter the rope radius"), ("keys", "c"), ("wait", "TARE BEFORE")]),
    ("calibrate-loading", CAL, [("wait", "Enter the rope radius"), ("keys", "c"), ("wait", "TARE BEFORE"),
                                ("keys", "c"), ("wait", "LOADING")]),
    ("calibrate-collecting", CAL, [("wait", "Enter the rope radius"), ("keys", "c"), ("wait", "TARE BEFORE"),
                                   ("keys", "c"), ("wait", "LOADING"), ("keys", "c")]),  # closed mid-collection
    ("calibrate-review", CAL, [("wait", "Enter the rope radius"), ("until", "c", "REVIEW", 90)]),
    ("calibrate-aborted", CAL, [("wait", "Enter the rope radius"), ("keys", "Space"), ("wait", "ABORTED")]),
    ("run-start-up", RUN, None),
    ("run-mid-test", RUN, [("wait", "ETA"), ("sleep", 1.5)]),  # the tty status line: state, point n, ETA
    ("replay-start-up", ["replay"], None),
    ("replay-viewer", ["replay"], [("wait", "eff %")]),
    ("firmware-sim-start-up", ["firmware-sim", "--elf", str(ELF), "--seconds", "600"], None),
    ("firmware-sim-running", ["firmware-sim", "--elf", str(ELF), "--seconds", "600"], [("sleep", 4.0)]),
]

needs = pytest.mark.skipif(shutil.which("tmux") is None or shutil.which("pgrep") is None,
                           reason="needs tmux and pgrep")


@pytest.fixture(scope="module")
def logged_run(tmp_path_factory) -> Path:
    """A short run for the replay viewer (coast-down: ~6 s)."""
    out = tmp_path_factory.mktemp("hup-replay") / "run"
    p = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--plan", "coast-down",
                        "--out", str(out)], capture_output=True, text=True, timeout=300, cwd=out.parent,
                       env={**os.environ, "PYTHONPATH": str(REPO)})
    assert p.returncode == 0, p.stderr[-2000:]
    return out


def _walk(session: Terminal, steps) -> None:
    for step in steps:
        if step[0] == "wait":
            session.wait(step[1], 150)  # (a busy 2-core machine: the app and the sim start slowly)
        elif step[0] == "keys":
            time.sleep(0.3)  # the screen is drawn before its widget takes keys
            session.keys(step[1])
        elif step[0] == "sleep":
            time.sleep(step[1])
        else:  # ("until", key, needle, timeout_s): press until the screen shows it
            _, key, needle, timeout_s = step
            t_end = time.monotonic() + timeout_s
            while needle not in session.screen() and time.monotonic() < t_end:
                session.keys(key)
                time.sleep(0.5)
            session.wait(needle, 5)


def _records(runs: Path) -> dict:
    """Each run directory's document types in order, its abort causes and its safety document."""
    out = {}
    for d in sorted(runs.iterdir()) if runs.is_dir() else []:
        docs_path = d / "documents.jsonl"
        if docs_path.is_file():
            docs = [json.loads(line) for line in docs_path.read_text().splitlines() if line.strip()]
            out[d] = {"types": [x["type"] for x in docs], "aborts": [x for x in docs if x["type"] == "abort"],
                      "safety": next((x for x in docs if x["type"] == "safety"), None)}
    return out


@needs
@pytest.mark.parametrize("case, command, steps", CASES, ids=[c[0] for c in CASES])
def test_entry_point_ends_safe_state_first_when_its_terminal_goes(case, command, steps, tmp_path, request,
                                                                  terminal):
    if command[0] == "firmware-sim":
        sim_elf()  # built here if no firmware test has built it yet (skips only without the toolchain)
    runs = tmp_path / "runs"
    history = tmp_path / "cal_history.csv"
    seed = str(40_000 + uuid.uuid4().int % 10_000)
    if command[0] == "replay":  # (no --seed: a run directory of its own name marks the process)
        run = tmp_path / f"run-{seed}"
        shutil.copytree(request.getfixturevalue("logged_run"), run)
        args = ["replay", str(run)]
    else:
        args = [*command, "--seed", seed] + (["--history", str(history)] if command[0] == "calibrate" else [])
    marker = "dyno " + " ".join(args)
    name = terminal("bash --norc", size=(100, 30), cwd=tmp_path)
    try:
        # "EXI""TED": the typed line itself must not read as the program's end to Terminal.wait
        name.keys(
             f"DYNO_RUNS_DIR={runs} PYTHONPATH={REPO} {sys.executable} -m dyno {' '.join(args)}; echo \"EXI\"\"TED=$?\"", "Enter")
        t_launch = time.monotonic()
        if steps is None:
            while not pids_matching(marker) and time.monotonic() - t_launch < 10:
                time.sleep(0.02)
            time.sleep(max(0.0, STARTUP_S - (time.monotonic() - t_launch)))
        else:
            _walk(name, steps)
        pids = pids_matching(marker)
        assert pids, f"not running before the pane closed:\n{name.screen()}"
        for pid in list(pids):  # its children too (firmware-sim's simavr harness)
            pids += [int(x) for x in subprocess.run(["pgrep", "-P", str(pid)], capture_output=True,
                                                    text=True).stdout.split()]
    finally:
        name.hang_up()  # SIGHUP, as a closed pane or a lost SSH session sends it (the fixture ends what is left)
    gone_s = seconds_until_gone(pids, timeout_s=15)
    if os.environ.get("DYNO_HUP_FIGURES"):  # a file to collect the figures in (docs/safety.md)
        with open(os.environ["DYNO_HUP_FIGURES"], "a") as f:
            f.write(f"{case} {gone_s:.2f}\n")
    assert gone_s < 15, "still running 15 s after its terminal closed"
    assert gone_s <= GONE_BOUND_S

    # Safe state first: what the command recorded on its way out.
    records = _records(runs)
    if steps is not None:
        for d, r in records.items():
            assert r["types"][-2:] == ["safety", "stop"], (d.name, r["types"][-4:])  # closed, safety last
            outs = r["safety"]["outputs"]
            assert outs["throttle"] == "idle" and outs["engine_kill"] == "killed", outs
            assert outs["pads_off_rotor"] is True, outs  # the brake let go before the process did
        if records:  # every run the command closed is in the run library
            conn = sqlite3.connect(runs / "library.sqlite")
            try:
                indexed = {r[0] for r in conn.execute("SELECT path FROM runs")}
            finally:
                conn.close()
            assert {str(d.resolve()) for d in records} <= indexed
    if case in ("ui-test-running", "run-mid-test", "ui-armed"):
        (r,) = records.values()
        assert r["aborts"] and r["aborts"][-1]["cause"] == "signal" and "SIGHUP" in r["aborts"][-1]["detail"]
    if command[0] == "calibrate":
        assert not history.exists()  # a calibration cut short writes nothing
