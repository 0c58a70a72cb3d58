#!/usr/bin/env python3
"""UI soak: ``dyno ui --sim --speed N`` as the operator runs it, test after test with re-arms, its RSS over time.

The real process in tmux (as tests/e2e/test_ui_drill_process.py drives it): wait for ARMED, ``g`` and ``y``
(GO), wait for the test to end — every ``--estop-every``-th test (the first, then every Nth after it) is stopped mid-test with the E-STOP key
(space) instead, so re-arms after an abort are soaked too — then ``r`` (repeated while the UI refuses: the
brake still releasing, the engine still turning) and ``y``, until ``--hours`` simulated hours have passed
(the UI's simulated clock is its loop's clock x speed).  After every test one line: tests, simulated
hours, state, the UI process's RSS (VmRSS) and open file descriptors.  At the end ``q`` ``y`` (quit), and
each run directory is checked: its ``safety`` document says the rig safe with the pads off the rotor, and
its points replay.

    python bench/bench_soak_ui.py [--hours 2] [--speed 8] [--plan speed-hold] [--quick] [--json]

``--quick`` (CI's smoke run): 2.5 simulated minutes at x4: the first test E-stopped mid-test, re-armed, the
second run to its end (~1.5–2 min of wall time).  Skips in one
line without tmux.  Exit 0 when the UI ran to the end, every run is safe and replays, and RSS after the
first quarter grew by at most 10 % (judged from 3 tests on), fds flat, and no test that was not E-stopped ended
without a point; 1 otherwise.  Nothing is judged on wall time: the waits for a screen are give-ups with the headroom
a 2x slower, loaded machine needs, and a watchdog trip of a loop starved at ``--speed N`` (a slow machine's, not a
fault of the session's) is met as the operator meets it, by starting ``dyno ui`` again.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

RSS_GROWTH_MAX = 0.10
ENDED = (" DONE ", " ABORTED ")  # the state line's first word once a test has ended
NO_REARM = "quit and start dyno again"  # the UI's refusal after a software fault (dyno.ui.session.NO_REARM)


class Restart(Exception):
    """The UI refused the re-arm for good: quit and start it again, as the operator is told to."""


def tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], capture_output=True, text=True, timeout=20).stdout


def pane(name: str) -> str:
    return tmux("capture-pane", "-p", "-t", name)


def wait_any(name: str, needles, timeout_s: float) -> tuple[str, str]:
    """(the needle seen, the screen); AssertionError naming the screen when none came in time."""
    t_end = time.monotonic() + timeout_s
    screen = ""
    while time.monotonic() < t_end:
        screen = pane(name)
        for n in needles:
            if n in screen:
                return n, screen
        if "EXITED=" in screen:
            break
        time.sleep(0.3)
    raise AssertionError(f"none of {needles!r} on screen within {timeout_s:.0f} s:\n{screen}")


def proc_figures(pid: int) -> tuple[float, int]:
    """(VmRSS MB, open fds) of the UI process."""
    rss_kb = 0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss_kb = int(line.split()[1])
    return rss_kb / 1024.0, len(os.listdir(f"/proc/{pid}/fd"))


def ui_pid(name: str, timeout_s: float = 30.0) -> int:
    """The dyno process: the child of the pane's shell (the shell stays to print EXITED=)."""
    shell = tmux("display", "-p", "-t", name, "#{pane_pid}").strip()
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        kids = subprocess.run(["pgrep", "-P", shell], capture_output=True, text=True).stdout.split()
        if kids:
            return int(kids[0])
        time.sleep(0.2)
    raise AssertionError(f"no dyno process under the pane's shell {shell}")


def one_test(name: str, estop: bool, test_timeout_s: float) -> str:
    """GO, the test to its end (or E-STOP mid-test), then re-arm; the state the test ended in."""
    seen, _ = wait_any(name, [" ARMED ", *ENDED], 150)  # (a busy 2-core machine: the first start is slow)
    if seen == " ARMED ":  # (else it ended before GO, e.g. the engine did not start: re-armed all the same)
        tmux("send-keys", "-t", name, "g")
        wait_any(name, ["Start the test?"], 60)
        tmux("send-keys", "-t", name, "y")
        if estop:
            wait_any(name, [" MEASURE ", " SETTLE ", " STEP "], 120)
            tmux("send-keys", "-t", name, "Space")
    ended, screen = wait_any(name, list(ENDED), test_timeout_s)
    cause = next((line.split("cause:", 1)[1].strip()[:90] for line in screen.splitlines() if " cause: " in line), "")
    t_end = time.monotonic() + 120  # re-arm as the operator does: ask until the release has ended
    while True:
        tmux("send-keys", "-t", name, "r")
        try:
            answer, _ = wait_any(name, ["Re-arm?", NO_REARM], 2)
            if answer == NO_REARM:  # after a software fault (the watchdog, ...) the operator starts dyno again
                raise Restart(pane(name))
            break
        except AssertionError:
            if time.monotonic() > t_end:
                raise
    title = pane(name).splitlines()[0]  # names the run directory: a new one once the re-arm has been done
    tmux("send-keys", "-t", name, "y")
    t_end = time.monotonic() + 120
    while pane(name).splitlines()[0] == title:  # (else the next test would read this one's stale screen)
        if time.monotonic() > t_end:
            raise AssertionError(f"re-armed, but the screen still shows {title!r}")
        time.sleep(0.3)
    return ended.strip() + (f" ({cause})" if cause else "") + ("" if seen == " ARMED " else " before GO")


def check_runs(root: Path) -> dict:
    """Every run directory the session left: safe at the end with the pads off, and its points replay."""
    from dyno.library.index import find_run_dirs
    from dyno.runlog.replay import replay
    from dyno.runlog.reader import load_run

    dirs = find_run_dirs(root)
    unsafe, unreplayable = [], []
    for d in dirs:
        run = load_run(d)
        safety = run.docs("safety")
        s = safety[-1] if safety else {}
        if not (s.get("rig_safe") and (s.get("outputs") or {}).get("pads_off_rotor")):
            unsafe.append(d.name)
        try:
            if len(replay(d)["points"]) != len(run.points):
                unreplayable.append(d.name)
        except Exception as exc:  # noqa: BLE001 - reported
            unreplayable.append(f"{d.name}: {type(exc).__name__}: {exc}")
    return {"run_dirs": len(dirs), "unsafe": unsafe, "unreplayable": unreplayable}


def soak(args) -> dict:
    work = Path(tempfile.mkdtemp(prefix="dyno-soak-ui-"))
    root = work / "runs"
    name = f"dyno-soak-ui-{uuid.uuid4().hex[:8]}"
    log = sys.stderr if args.json else sys.stdout
    # (in the command: a tmux server that is already running gives a new session its own environment)
    from dyno.model.cache_keys import default_cache_dir

    cache = default_cache_dir()  # the belt-model table's cache (HOME is the work dir: a cold cache costs minutes)
    cmd = (f"env PYTHONPATH={shlex.quote(str(REPO))} DYNO_RUNS_DIR={shlex.quote(str(root))} "
           f"DYNO_MODEL_CACHE={shlex.quote(str(cache))} "
           f"{shlex.quote(sys.executable)} -m dyno ui --sim --speed {args.speed:g} --plan {shlex.quote(args.plan)} "
           f"--seed {args.seed} ; echo EXITED=$? ; sleep 30")
    env = {"TERM": "xterm-256color", "PATH": os.environ.get("PATH", ""), "HOME": str(work)}
    samples, states, restarts, error, exited = [], [], [], None, None
    wall0 = time.monotonic()
    sim_before_s = 0.0  # simulated time of the processes before a restart
    try:
        while True:  # one dyno ui process; again after a restart
            subprocess.run(["tmux", "new-session", "-d", "-x", "120", "-y", "40", "-s", name, "-c", str(work), cmd],
                           check=True, timeout=20, env=env)
            pid = ui_pid(name)
            wait_any(name, [" ARMED "], 300)  # (start-up on a loaded 2-core machine: seen > 150 s)
            t0 = time.monotonic()  # the UI's simulated clock runs from about here (its first frame)
            print(f"soak-ui: dyno ui pid {pid}, x{args.speed:g}, {args.hours:g} simulated h, runs in {root}",
                  file=log, flush=True)
            try:
                while sim_before_s + (time.monotonic() - t0) * args.speed < args.hours * 3600.0:
                    k = len(states) + 1
                    try:
                        states.append(one_test(name, args.estop_every > 0 and (k - 1) % args.estop_every == 0,
                                               args.test_timeout_s))
                    except Restart as why:
                        states.append("ABORTED")
                        restarts.append({"test": k, "pid": pid, "screen": str(why)[-600:]})
                        raise
                    rss, fds = proc_figures(pid)
                    sim_h = (sim_before_s + (time.monotonic() - t0) * args.speed) / 3600.0
                    samples.append({"test": k, "pid": pid, "sim_h": round(sim_h, 3), "state": states[-1],
                                    "wall_s": round(time.monotonic() - wall0, 1), "rss_mb": round(rss, 1), "fds": fds})
                    print(f"[{sim_h:6.2f} h sim, {samples[-1]['wall_s']:6.0f} s wall] test {k:3d} {states[-1]} "
                          f"re-armed; RSS {rss:6.1f} MB fds {fds}", file=log, flush=True)
            except Restart:
                print(f"soak-ui: test {len(states)}: re-arm refused ({NO_REARM}): quit, start dyno ui again",
                      file=log, flush=True)
                sim_before_s += (time.monotonic() - t0) * args.speed
                tmux("send-keys", "-t", name, "q")  # (an ended test: quits without asking)
                wait_any(name, ["EXITED="], 120)
                tmux("kill-session", "-t", name)
                continue
            break
        tmux("send-keys", "-t", name, "q")
        wait_any(name, ["Quit?"], 60)
        tmux("send-keys", "-t", name, "y")
        wait_any(name, ["EXITED="], 120)
        exited = pane(name).split("EXITED=")[1].split()[0]
    except AssertionError as exc:
        error = str(exc)[-1500:]
    finally:
        tmux("kill-session", "-t", name)
    runs = check_runs(root) if root.is_dir() else {"run_dirs": 0, "unsafe": [], "unreplayable": []}
    # RSS flat: the last process's samples, from a quarter of the soak on (start-up and caches done)
    last_pid = samples[-1]["pid"] if samples else None
    settled = [s for s in samples if s["sim_h"] >= args.hours / 4 and s["pid"] == last_pid]
    growth = (max(s["rss_mb"] for s in settled) / settled[0]["rss_mb"] - 1.0) if len(settled) >= 3 else None
    fds = [s["fds"] for s in settled]
    checks = {"ran_to_the_end": error is None and exited == "0", "every_run_safe": not runs["unsafe"],
              "every_run_replays": not runs["unreplayable"],
              # a test that was not E-stopped measured something (a re-armed x4 session once held no setpoint)
              "every_test_measured": not any("no_points" in x for x in states),
              # (None: too few tests to judge a trend, e.g. --quick)
              "rss_flat": None if growth is None else growth <= RSS_GROWTH_MAX,
              "fds_flat": None if len(fds) < 3 else max(fds) - min(fds) <= 1}
    if error is None and not runs["unsafe"] and not runs["unreplayable"] and checks["every_test_measured"]:
        shutil.rmtree(work, ignore_errors=True)
    else:  # kept for a look: the runs of a soak that found something
        print(f"soak-ui: kept {work}", file=log, flush=True)
    ended = Counter(x.split(" ")[0] for x in states)  # DONE / ABORTED (the causes are in the samples)
    return {"hours": args.hours, "speed": args.speed, "tests": len(states), "ended": dict(ended),
            "wall_s": round(time.monotonic() - wall0, 1), "samples": samples, "restarts": restarts,
            "rss_growth": None if growth is None else round(growth, 4), "runs": runs, "error": error,
            "checks": checks, "ok": all(v is not False for v in checks.values())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=2.0, help="simulated hours (default 2)")
    ap.add_argument("--speed", type=float, default=8.0, help="dyno ui --speed (default 8)")
    ap.add_argument("--plan", default="speed-hold")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--estop-every", type=int, default=3, help="E-STOP every Nth test mid-test (0: never)")
    ap.add_argument("--test-timeout-s", type=float, default=900.0, help="wall seconds one test may take")
    ap.add_argument("--quick", action="store_true", help="CI smoke run: an E-stopped test and a whole one at x4")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:  # (x4: a loaded CI machine starves x8's loop into watchdog trips)
        # a test E-stopped mid-test, re-armed, and one run to its end (~3.5 simulated minutes)
        args.hours, args.speed, args.estop_every = 2.5 / 60, 4.0, 2
    if shutil.which("tmux") is None:
        print("bench_soak_ui: skipped: tmux is not installed")
        return 0
    import signal

    def stop(signum, frame):  # (SystemExit: the tmux session is closed by soak()'s finally)
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, stop)
    out = soak(args)
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"soak-ui: {out['tests']} tests {out['ended']} in {out['wall_s']:.0f} s wall; RSS growth "
              f"{out['rss_growth']}; runs {out['runs']}; " + ", ".join(f"{k} {v}" for k, v in out["checks"].items()))
        if out["error"]:
            print("error:", out["error"], file=sys.stderr)
    return 0 if out["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
