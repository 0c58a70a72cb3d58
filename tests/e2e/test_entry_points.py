"""Every `dyno` command started as a user starts it: a real process (`python3 -m dyno ...`), the viewers in a
real terminal (tmux).  A start-up crash of any entry point fails here, not on a user's machine.

One simulated run (module fixture) feeds the commands that read a run.
"""

from __future__ import annotations

import csv
import contextlib
import io
import json
import re
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.cli import COMMANDS
from dyno.datapaths import legacy_data_dir, legacy_data_missing

REPO = Path(__file__).resolve().parents[2]
LEGACY_RUN = "2019-04-18_run2"
needs_tmux = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")

#: commands this module starts as processes; the others are started as processes where named
EXERCISED = {"run", "replay", "export", "import-legacy", "model", "firmware-sim", "calibrate", "doctor",
             "shift-curve", "design", "arcvt"}
EXERCISED_ELSEWHERE = {"ui": "tests/ui/test_ui_tmux.py", "report": "tests/e2e/test_report.py",
                       "runs": "tests/library/test_index.py", "compare": "tests/library/test_compare.py",
                       "serve": "tests/web/test_web_serve.py", "tune": "tests/tuning/test_tune_advise.py",
                       "init": "tests/packaging/test_wheel.py", "flash": "tests/hw/test_hw_flash.py"}


def _env(**extra: str) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO)  # this tree, not whatever is pip-installed
    env.update(extra)
    return env


def dyno(*args, cwd: Path, timeout: float = 120, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd, env=_env(**env))


def _ok(proc: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    return proc


# --- tmux ----------------------------------------------------------------------------------------
def dyno_terminal(terminal, args, cwd: Path):
    """A 120x40 terminal (tests/screens.py) running one dyno command; the shell line after it reports the exit
    code."""
    cmd = " ".join([sys.executable, "-m", "dyno", *map(str, args)]) + " ; echo EXITED=$? ; sleep 30"
    return terminal(cmd, size=(120, 40), cwd=cwd, env={"HOME": str(cwd), "PYTHONPATH": str(REPO)})


# --- one simulated run for the module -------------------------------------------------------------
@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("entry")


@pytest.fixture(scope="module")
def sim_run(cli_run):
    """`dyno run --sim --headless --json` as a process (tests/e2e/conftest.py): (run directory, its JSON)."""
    return cli_run


def test_every_command_is_started_as_a_process():
    assert set(COMMANDS) <= EXERCISED | set(EXERCISED_ELSEWHERE), set(COMMANDS) - EXERCISED


def test_entry_dyno_version_and_help(work):
    assert _ok(dyno("--version", cwd=work)).stdout.strip()
    out = _ok(dyno("--help", cwd=work)).stdout
    assert all(name in out for name in COMMANDS)


def test_entry_run_sim_headless_json(sim_run):
    run_dir, doc = sim_run
    assert doc["state"] == "done" and doc["rig_safe"] is True and not doc["aborts"]
    assert len(doc["points"]) >= 10
    assert all(0.5 < p["efficiency"] < 1.0 for p in doc["points"] if p.get("valid", True))
    for name in ("meta.json", "documents.jsonl", "events.bin", "calibration.json"):
        assert (run_dir / name).is_file(), name
    assert '"type": "stop"' in (run_dir / "documents.jsonl").read_text()
    # each setpoint that gave no point, with why: the run's skip documents, in the JSON and the text summary
    docs = [json.loads(x) for x in (run_dir / "documents.jsonl").read_text().splitlines() if x.strip()]
    skips = [d["reason"] for d in docs if d.get("type") == "skip"]
    assert skips and doc["skipped"] == skips  # (the speed-hold plan's setpoints in the shift region)
    from dyno.cli.run_cmd import print_result_table

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        print_result_table(doc)
    assert all(f"skipped: {why}" in buf.getvalue() for why in skips)


def test_entry_replay_json_reproduces_the_run(sim_run, work):
    run_dir, doc = sim_run
    rep = json.loads(_ok(dyno("replay", run_dir, "--json", cwd=work)).stdout)
    assert len(rep["points"]) == len(doc["points"])
    for live, again in zip(doc["points"], rep["points"]):
        assert again["efficiency"] == pytest.approx(live["efficiency"], rel=1e-9)
        assert again["rpm_secondary"] == pytest.approx(live["rpm_secondary"], rel=1e-9)


@needs_tmux
def test_entry_replay_viewer_shows_the_points_table(sim_run, work, terminal):
    run_dir, doc = sim_run
    term = dyno_terminal(terminal, ["replay", run_dir], cwd=work)
    try:
        screen = term.wait(["T N·m", "eff %", "efficiency vs secondary rpm"], 60)
        assert f"{len(doc['points'])} points" in screen and "run 1/1" in screen
        # every point's secondary rpm and efficiency as the table prints them (38 rows fit in 40 lines)
        for p in doc["points"]:
            assert f"{p['rpm_secondary']:.0f}" in screen and f"{100 * p['efficiency']:.1f}" in screen, p["index"]
        term.keys("q")
        term.wait("EXITED=0", 20)
    finally:
        term.close()


@needs_tmux
def test_entry_calibrate_sim_starts_and_quits(work, terminal):
    history = work / "cal_history.csv"
    term = dyno_terminal(terminal, ["calibrate", "--sim", "--history", history], cwd=work)
    try:
        screen = term.wait(["SETUP", "E-STOP", "ADC now"], 60)
        assert "Enter the rope radius and the masses" in screen
        term.keys("C-q")
        term.wait("EXITED=0", 20)
    finally:
        term.close()
    assert not history.exists()  # nothing was collected or accepted: nothing written


def test_entry_export_writes_the_points(sim_run, work):
    run_dir, doc = sim_run
    out = work / "export"
    _ok(dyno("export", run_dir, "--out", out, cwd=work))
    with open(out / "points.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(doc["points"])
    for name in ("primary_edges.csv", "secondary_edges.csv", "adc.csv"):
        assert (out / name).stat().st_size > 100, name


@pytest.fixture(scope="module")
def legacy_run(work):
    """`dyno import-legacy` on the thesis logs from $DYNO_LEGACY_DATA: (run directory, JSON document)."""
    why = legacy_data_missing()
    if why:
        pytest.skip(why)
    out = work / "legacy"
    proc = _ok(dyno("import-legacy", legacy_data_dir() / LEGACY_RUN, "--out", out, "--json", cwd=work))
    return out, json.loads(proc.stdout)


def test_entry_import_legacy(legacy_run, work):
    out, doc = legacy_run
    assert len(doc["points"]) >= 5 and (out / "documents.jsonl").is_file()
    rep = json.loads(_ok(dyno("replay", out, "--json", cwd=work)).stdout)
    assert [p["index"] for p in rep["points"]] == [p["index"] for p in doc["points"]]


def test_entry_import_legacy_missing_folder_is_one_line(work, tmp_path):
    missing = tmp_path / "nowhere"
    proc = dyno("import-legacy", missing / LEGACY_RUN, "--out", tmp_path / "o", cwd=work)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and str(missing) in proc.stderr
    assert not (tmp_path / "o").exists()


def test_entry_model_point_json(work):
    doc = json.loads(_ok(dyno("model", "point", "--json", cwd=work)).stdout)
    assert doc["converged"] is True and doc["residual_max"] <= doc["tol"]


def test_entry_shift_curve_over_the_run(sim_run, work):
    run_dir, doc = sim_run
    tune = REPO / "calibration" / "tunes" / "cvtech-stock.toml"
    out = _ok(dyno("shift-curve", tune, "--run", run_dir, "--points", 12, "--no-sensitivity", cwd=work)).stdout
    assert "predicted shift curve: cvtech-stock" in out and "engagement" in out and "full shift" in out
    js = json.loads(_ok(dyno("shift-curve", tune, "--points", 12, "--no-sensitivity", "--json",
                             cwd=work)).stdout)
    assert js  # a curve came back


def test_entry_design(work):
    out = work / "design"
    req = REPO / "calibration" / "design" / "arango-munoz-2020-example.toml"
    doc = json.loads(_ok(dyno("design", "--requirements", req, "--out", out, "--json", cwd=work)).stdout)
    assert doc["requirements"]["name"] == "arango-munoz-2020-example"
    assert (out / "design.json").is_file() and (out / "summary.txt").is_file()


def test_entry_arcvt(work):
    doc = json.loads(_ok(dyno("arcvt", "--points", 5, "--json", cwd=work)).stdout)
    assert doc["params"]["clamp_force_n"] > 0


def test_entry_firmware_sim_missing_elf_is_one_line(work):
    proc = dyno("firmware-sim", "--elf", work / "absent.elf", cwd=work)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().count("\n") == 0 and "make -C firmware sim" in proc.stderr


def test_entry_firmware_sim(work):
    from tests.fw_build import sim_elf

    elf = sim_elf()
    proc = _ok(dyno("firmware-sim", "--elf", elf, "--seconds", 0.5,
                    "--json", cwd=work, timeout=300))
    doc = json.loads(proc.stdout)
    assert doc["ok"] is True and doc["events_lost"] == 0
    # the text output rounds its figures (the JSON keeps every digit): no "3799.9993968254926"
    text = _ok(dyno("firmware-sim", "--elf", elf, "--seconds", 0.5, cwd=work, timeout=300)).stdout
    line = next(x for x in text.splitlines() if "rpm primary" in x)
    assert re.search(r"rpm primary \d+\.\d{2} \([+-]\d+\.\d{3} %\), secondary \d+\.\d{2} \([+-]\d+\.\d{3} %\), "
                     r"adc mean \d+\.\d$", line), line
    assert not re.search(r"\d\.\d{5,}", text), text


def test_entry_doctor_sim(work):
    out = _ok(dyno("doctor", "--sim", cwd=work)).stdout
    assert "ok  firmware" in out and "ok  thermometer" in out and "FAIL" not in out


@pytest.mark.skipif(Path("/dev/i2c-3").exists(), reason="the rig's I2C bus is present: this is a rig, not CI")
def test_entry_doctor_without_hardware_says_what_fails(work):
    proc = dyno("doctor", "--rig", REPO / "hardware" / "rig.toml", cwd=work)  # (a rig file of its own: no refusal)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr + proc.stdout
    assert "FAIL  i2c bus" in proc.stdout and "rig NOT ready" in proc.stdout


# --- closed pipes and Ctrl+C ----------------------------------------------------------------------
def _closed_pipe(*args, cwd: Path, timeout: float = 300):
    """Run `dyno ARGS` with its stdout's reader gone before it writes (like `| head` that has had enough)."""
    proc = subprocess.Popen([sys.executable, "-m", "dyno", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=cwd, env=_env())
    proc.stdout.close()
    err = proc.stderr.read()
    return proc.wait(timeout=timeout), err


@pytest.mark.parametrize("args", [("arcvt",), ("model", "point", "--json"), ("doctor", "--sim"),
                                  ("replay", "RUN", "--json")])
def test_closed_pipe_ends_quietly_with_141(args, sim_run, work):
    args = [sim_run[0] if a == "RUN" else a for a in args]
    rc, err = _closed_pipe(*args, cwd=work)
    assert rc == 141 and "Traceback" not in err and "BrokenPipe" not in err, (rc, err)


def test_closed_pipe_keeps_a_runs_exit_code(work):
    """`dyno run ... | head`: the test still runs to its end, on disk, and its exit code says how it ended."""
    out = work / "piped-run"
    rc, err = _closed_pipe("run", "--sim", "--headless", "--seed", 5, "--out", out, cwd=work)
    assert rc == 0 and "Traceback" not in err and "BrokenPipe" not in err, (rc, err)
    assert "ETA" not in err and "\r" not in err  # not a terminal: no progress line
    assert '"exit_status": "success"' in (out / "documents.jsonl").read_text()
    assert (out / "report.html").is_file()


def test_ctrl_c_outside_a_test_is_one_line_and_130(work):
    # (--no-cache and a cache of its own: a sweep read from an earlier run's cache could end before the signal)
    proc = subprocess.Popen([sys.executable, "-m", "dyno", "model", "sweep", "--points", "60", "--no-cache"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=work,
                            env=_env(DYNO_MODEL_CACHE=str(work / "model-cache")),
                            # as a terminal's foreground job has it: a suite started in the background (`... &`
                            # from a script) runs with SIGINT ignored, and a child inherits that
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        first = proc.stderr.readline()  # the sweep's start line: well inside the command (it solves next)
        assert first.startswith("dyno model sweep: 60 ratios"), first
        proc.send_signal(signal.SIGINT)
        err = proc.stderr.read()
        assert proc.wait(timeout=60) == 130
    finally:
        proc.kill()
    assert "Traceback" not in err and err.strip().splitlines()[-1] == "dyno model: interrupted", err[-1000:]
