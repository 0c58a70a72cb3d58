#!/usr/bin/env python3
"""UI benchmarks (issues 5, 13): CPU, poll-interval jitter with and without the UI, start-up time, peak memory.

Run:  python bench/bench_ui.py [--seconds S] [--cpu-seconds S] [--repeat N] [--cpu-only] [--profile armed|test|ended] [--quick]

1. CPU (issue 13): the live screen in an 80x24 pseudo-terminal (Textual's real driver, the output read
   as a terminal would), idle/ARMED, during a test and with the screen left up after it (E-STOP, the rig
   at rest), as % of one core, with the simulated bus read on
   the loop and again as the real rig reads its blocking bus (transfers in the poller's I/O thread); the simulated rig's own cost
   (emulated firmware + physics behind the I2C transport, per-thread CPU time) measured and subtracted:
   what is left is what the real-rig path costs (poller, controller, run log, UI).  The same for the
   session alone (no UI) shows the UI's share.
2. Jitter: the simulated rig in real time (speed 1) on an ordinary asyncio loop,
   poller at the rig's 150 Hz, test GO'd; first bare (poller + controller only),
   then inside the live screen (Textual headless driver: it renders every frame
   exactly as on a terminal), then the live screen with the belt-model overlay
   computing in its worker thread.  Reports the poll-interval statistics, frames,
   and events lost (0 = no frame missed).
3. Entry points: each of ``dyno ui --sim``, ``dyno calibrate --sim`` and
   ``dyno replay RUN`` started in a fresh interpreter, headless, until its first
   screen is mounted: wall time from process start, peak RSS, and whether the
   belt-model solver (dyno.model.bvp) was imported.

Prints figures; asserts nothing (the machine is shared and noisy).

``--quick`` (CI's smoke run, about 80 s): every part once on a smaller problem -- the CPU figures for the
session alone and the live screen with the rig's bus I/O (the plain live screen's path is within the latter),
2 s per phase; the jitter without the UI and with the UI + overlay (the plain UI's path is within the latter),
2 s each; the entry points -- with the simulated rig at 5x real time so that the waits for ARMED, the warm-up
and the spin-down are short, and the model cache's entries copied into its fresh cache (else the simulated
rig's belt table is built anew: about a minute).  Its figures are not the real-time ones.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _summary(poller) -> dict:
    s = poller.timing.summary()
    return {**s, "events_lost": poller.reader.events_lost, "frames": poller.reader.stats.accepted,
            "rejected": sum(poller.reader.stats.rejected.values())}


async def _bare(seconds: float, out_dir: Path, speed: float = 1.0) -> dict:
    from dyno.ui.session import LiveOptions, LiveSession

    s = LiveSession(LiveOptions(sim=True, speed=speed, out_dir=out_dir))
    s.start()
    t_end = asyncio.get_running_loop().time() + seconds + 15
    while s.controller.state.value != "armed" and asyncio.get_running_loop().time() < t_end:
        await asyncio.sleep(0.05)
    s.poller.timing.intervals_s.clear()  # measure the test, not the engine start
    s.go()
    await asyncio.sleep(seconds)
    out = _summary(s.poller)
    out["state"] = s.controller.state.value
    await s.close("bench")
    return out


async def _with_ui(seconds: float, out_dir: Path, overlay: bool, speed: float = 1.0) -> dict:
    from dyno.ui.live_app import LiveApp
    from dyno.ui.session import LiveOptions

    app = LiveApp(LiveOptions(sim=True, speed=speed, out_dir=out_dir))
    async with app.run_test(size=(80, 24)) as pilot:
        t_end = time.monotonic() + 20
        while (app.session is None or app.session.controller.state.value != "armed") and time.monotonic() < t_end:
            await asyncio.sleep(0.05)
        s = app.session
        s.poller.timing.intervals_s.clear()
        await pilot.press("g")
        await pilot.press("y")
        if overlay:
            # points for the overlay to work on: the run has none yet after a few seconds, so hand it some
            fake = [{"rpm_primary": 3300.0 + 50 * i, "ratio": 1.5 - 0.1 * i, "power_in_w": 5200.0,
                     "rpm_secondary": 2200.0 + 200 * i, "efficiency": 0.85} for i in range(4)]
            app.overlay_requested = True
            app.run_worker(lambda: app._overlay_submit_work(fake, time.monotonic()), thread=True,
                           exclusive=True, group="overlay")
        for key in "123" * int(max(1, seconds // 3)):
            await asyncio.sleep(1.0)
            await pilot.press(key)  # switch plots: the heaviest redraws
        out = _summary(s.poller)
        out["state"] = s.controller.state.value
        out["overlay_tier"] = app.overlay_tier
        await pilot.press("space")
        await pilot.press("q")
    return out


STARTUP_SCRIPT = r"""
import time, sys, os
T0 = float(os.environ["BENCH_T0"])
import asyncio, json, resource
from pathlib import Path
which, arg = sys.argv[1], sys.argv[2]

async def main():
    if which == "ui":
        from dyno.ui.live_app import LiveApp
        from dyno.ui.session import LiveOptions
        app = LiveApp(LiveOptions(sim=True, out_dir=Path(arg)))
        ready = lambda: app.session is not None
    elif which == "calibrate":
        from dyno.ui.calibrate_app import CalibrateApp, CalibrateOptions
        app = CalibrateApp(CalibrateOptions(sim=True, history_path=Path(arg)))
        ready = lambda: app.poller is not None
    else:
        from dyno.ui.replay_app import ReplayApp
        app = ReplayApp([Path(arg)])
        ready = lambda: app.rs is not None
    import importlib
    from dyno.cli import COMMANDS
    importlib.import_module(COMMANDS[which][0])
    async with app.run_test(size=(80, 24)) as pilot:
        while not ready():
            await asyncio.sleep(0.01)
        await pilot.pause()  # first screen rendered
        t_ready = time.time() - T0
        await pilot.press("ctrl+q" if which != "ui" else "space")
        if which == "ui":
            await pilot.press("q")
    # VmHWM, not ru_maxrss: Linux carries ru_maxrss over from the parent through fork+exec.
    hwm = [l for l in open("/proc/self/status") if l.startswith("VmHWM:")]
    rss_mb = int(hwm[0].split()[1]) / 1024 if hwm else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"startup_s": t_ready, "peak_rss_mb": rss_mb, "bvp_imported": "dyno.model.bvp" in sys.modules}))

asyncio.run(main())
"""


def startup(which: str, arg: str) -> dict:
    env = {**os.environ, "BENCH_T0": repr(time.time())}
    proc = subprocess.run([sys.executable, "-c", STARTUP_SCRIPT, which, arg], capture_output=True, text=True,
                          timeout=180, env=env, cwd=REPO)
    if proc.returncode:
        return {"error": proc.stderr[-500:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


# --- CPU: the live screen in a real terminal (a pseudo-terminal), the simulated rig's own cost apart ----------
CPU_SCRIPT = r"""
import asyncio, json, os, sys, threading, time
from pathlib import Path

mode, out_dir, result_path = sys.argv[1], Path(sys.argv[2]), sys.argv[3]
armed_s, test_s = float(sys.argv[4]), float(sys.argv[5])
speed = float(sys.argv[6]) if len(sys.argv) > 6 else 1.0  # x real time (1: the figures; more: a smoke run)
profile_phase, profile_path = os.environ.get("BENCH_PROFILE", ""), os.environ.get("BENCH_PROFILE_OUT", "")

# The simulated rig's cost: everything behind the I2C transport (emulated firmware + physics, which the
# real rig does in its own hardware) and the truth recorder (sim only).  Per-thread CPU time, so the
# watchdog thread safing the rig is counted where it is spent.
from dyno.sim.bus import SimSMBus
from dyno.sim.rig import TruthRecorder

SIM = {"cpu_s": 0.0}
_inside = threading.local()


def timed(fn):
    def wrapper(*a, **k):
        if getattr(_inside, "on", False):
            return fn(*a, **k)
        _inside.on = True
        t = time.thread_time()
        try:
            return fn(*a, **k)
        finally:
            SIM["cpu_s"] += time.thread_time() - t
            _inside.on = False
    return wrapper


if mode.endswith("-rigio"):
    # The real rig's configuration: a blocking bus, transfers in the poller's I/O thread (the sim's
    # bus serialises its own access with a lock, as the kernel does a real adapter's).
    from dyno.acquisition import poller as _poller_mod

    _init = _poller_mod.Poller.__init__

    def _init_blocking(self, *a, **k):
        k["blocking_io"] = True
        _init(self, *a, **k)

    _poller_mod.Poller.__init__ = _init_blocking
    mode = mode[: -len("-rigio")]

SimSMBus.i2c_rdwr = timed(SimSMBus.i2c_rdwr)
SimSMBus.sync = timed(SimSMBus.sync)
TruthRecorder.__call__ = timed(TruthRecorder.__call__)


async def measure(name, seconds):
    prof = None
    if profile_phase == name:
        import cProfile
        prof = cProfile.Profile()
        prof.enable()
    c0, s0, w0 = time.process_time(), SIM["cpu_s"], time.monotonic()
    await asyncio.sleep(seconds)
    c1, s1, w1 = time.process_time(), SIM["cpu_s"], time.monotonic()
    if prof is not None:
        prof.disable()
        prof.dump_stats(profile_path)
    wall = w1 - w0
    return {"wall_s": wall, "total_pct": 100 * (c1 - c0) / wall, "sim_pct": 100 * (s1 - s0) / wall,
            "net_pct": 100 * ((c1 - c0) - (s1 - s0)) / wall}


async def drive(get_session, quit):
    while (s := get_session()) is None or s.controller.state.value != "armed":
        await asyncio.sleep(0.1)
    await asyncio.sleep(1.0)  # the state change's own redraws are done
    armed = await measure("armed", armed_s)
    s.go()
    await asyncio.sleep(4.0 / speed)  # through the warm-up: the test proper
    test = await measure("test", test_s)
    res = {"armed": armed, "test": test, "state": s.controller.state.value, "points": len(s.controller.points),
           "events_lost": s.poller.reader.events_lost}
    # The screen left up after the test: E-STOP, the rig spins down and the brake releases, then it rests.
    s.estop("bench")
    idle_period_s = 1.0 / s.controller.limits.armed_poll_hz
    t_end = time.monotonic() + 40.0
    while abs(s.poller.poll_period_s - idle_period_s) > 1e-9 and time.monotonic() < t_end:
        await asyncio.sleep(0.2)
    await asyncio.sleep(1.0)
    res["ended"] = await measure("ended", armed_s)
    Path(result_path).write_text(json.dumps(res))
    await quit()


async def main():
    from dyno.ui.session import LiveOptions
    opts = LiveOptions(sim=True, speed=speed, out_dir=out_dir)
    if mode == "ui":
        from dyno.ui.live_app import LiveApp
        app = LiveApp(opts)
        task = asyncio.get_running_loop().create_task(drive(lambda: app.session, app._quit))
        await app.run_async()
        await task
    else:
        from dyno.ui.session import LiveSession
        s = LiveSession(opts)
        s.start()
        await drive(lambda: s, lambda: s.close("bench"))

asyncio.run(main())
"""


def cpu(mode: str, out_dir: Path, armed_s: float, test_s: float, profile: str = "", speed: float = 1.0) -> dict:
    """Run the live screen (``mode`` "ui") or the session alone ("bare") in an 80x24 pseudo-terminal."""
    import fcntl
    import pty
    import select
    import struct
    import termios

    result = out_dir.parent / f"cpu-{mode}.json"
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    env = {**os.environ, "TERM": "xterm-256color", "COLUMNS": "80", "LINES": "24"}
    if profile:
        prof_path = Path(tempfile.gettempdir()) / f"bench-ui-cpu-{mode}-{profile}.prof"  # kept for pstats
        env.update(BENCH_PROFILE=profile, BENCH_PROFILE_OUT=str(prof_path))
    proc = subprocess.Popen([sys.executable, "-c", CPU_SCRIPT, mode, str(out_dir), str(result), str(armed_s),
                             str(test_s), str(speed)], stdin=slave, stdout=slave, stderr=slave, env=env, cwd=REPO,
                            start_new_session=True)
    os.close(slave)
    tail = b""
    t_end = time.monotonic() + 2 * armed_s + test_s + 160
    while time.monotonic() < t_end:  # a terminal reads what the app writes
        r, _, _ = select.select([master], [], [], 0.5)
        if r:
            try:
                data = os.read(master, 65536)
            except OSError:
                break
            if not data:
                break
            tail = (tail + data)[-4000:]
        elif proc.poll() is not None:
            break
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    os.close(master)
    if not result.is_file():
        return {"error": tail.decode(errors="replace")[-800:]}
    out = json.loads(result.read_text())
    if profile:
        import pstats

        out["profile"] = str(prof_path)
        print(f"profile of the {profile} phase: {prof_path}")
        pstats.Stats(out["profile"]).sort_stats("tottime").print_stats(20)
    return out


def fmt_cpu(name: str, d: dict) -> str:
    if "error" in d:
        return f"{name:<24} ERROR {d['error']}"
    a, t, e = d["armed"], d["test"], d["ended"]
    return (f"{name:<24} idle/ARMED {a['net_pct']:4.1f} %  (sim {a['sim_pct']:3.1f} %, all {a['total_pct']:4.1f} %)  "
            f"test {t['net_pct']:4.1f} %  (sim {t['sim_pct']:3.1f} %, all {t['total_pct']:4.1f} %)  "
            f"ended, at rest {e['net_pct']:4.1f} %  (sim {e['sim_pct']:3.1f} %)  "
            f"[{d['state']}, {d['points']} points, lost {d['events_lost']}]")


def fmt_timing(name: str, d: dict) -> str:
    if d.get("polls", 0) == 0:
        return f"{name:<26} no polls"
    return (f"{name:<26} polls {d['polls']:6d}  mean {d['mean_ms']:6.3f} ms  std {d['std_ms']:6.3f} ms  "
            f"p99 {d['p99_ms']:6.2f} ms  max {d['max_ms']:7.2f} ms  frames {d['frames']:6d}  "
            f"lost {d['events_lost']}  [{d['state']}]")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=8.0, help="real-time seconds per jitter measurement")
    ap.add_argument("--quick", action="store_true",
                    help="CI smoke run (about 80 s): each part once, 2 s per measurement, the simulated rig at "
                         "5x real time, the plain live screen left out (its path is within the runs kept)")
    ap.add_argument("--cpu-seconds", type=float, default=20.0, help="seconds per CPU measurement phase")
    ap.add_argument("--cpu-only", action="store_true", help="only the CPU figures")
    ap.add_argument("--repeat", type=int, default=3, help="CPU runs per mode (the median is printed)")
    ap.add_argument("--profile", choices=("armed", "test", "ended"), default="",
                    help="cProfile this phase of the live screen's CPU run (top 25 by cumulative time)")
    a = ap.parse_args()
    seconds = 2.0 if a.quick else a.seconds
    cpu_s = 2.0 if a.quick else a.cpu_seconds
    speed = 5.0 if a.quick else 1.0
    pace = "in real time" if speed == 1.0 else f"at {speed:g}x real time (--quick: not the real-time figures)"
    if a.quick:
        a.repeat = 1
    quick_cache = None
    if a.quick and "DYNO_MODEL_CACHE" not in os.environ:
        # A fresh cache as below, but with this machine's entries in it: the simulated rig's belt table is read,
        # not built again (about a minute); removed at the end.
        import shutil

        from dyno.model.overlay import default_cache_dir

        quick_cache = Path(tempfile.mkdtemp(prefix="bench-ui-cache-"))
        if default_cache_dir().is_dir():
            for entry in default_cache_dir().glob("*.json"):
                shutil.copy2(entry, quick_cache)
        os.environ["DYNO_MODEL_CACHE"] = str(quick_cache)
    try:
        _run(a, seconds, cpu_s, speed, pace)
    finally:
        if quick_cache is not None:
            import shutil

            shutil.rmtree(quick_cache, ignore_errors=True)


def _run(a, seconds: float, cpu_s: float, speed: float, pace: str) -> None:
    if "DYNO_MODEL_CACHE" not in os.environ:  # (not setdefault: that would make a directory either way)
        os.environ["DYNO_MODEL_CACHE"] = tempfile.mkdtemp(prefix="bench-ui-cache-")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        print(f"CPU, % of one core, simulated rig {pace}, 80x24 pseudo-terminal, {cpu_s:g} s per phase; "
              "'idle/ARMED' and 'test' are net of the simulated rig (its firmware + physics, shown as 'sim'):")
        runs: dict = {"bare": [], "ui": [], "ui-rigio": []}
        for k in range(a.repeat):  # alternated: the shared machine's load drifts
            for mode, name in (("bare", "session alone (no UI)"), ("ui", "live screen (dyno ui)"),
                               ("ui-rigio", "live screen, rig bus I/O")):
                if a.quick and mode == "ui" and not a.profile:
                    print(f"{name:<24} left out by --quick (the rig bus I/O run is this one's path and more)")
                    continue
                d = cpu(mode, tmp / f"cpu_{mode}_{k}", cpu_s, cpu_s, a.profile if mode == "ui" else "", speed)
                runs[mode].append(d)
                print(fmt_cpu(name, d))
        if a.repeat > 1:
            import statistics

            med = {m: {ph: statistics.median(d[ph]["net_pct"] for d in r if "error" not in d)
                       for ph in ("armed", "test", "ended")} for m, r in runs.items()}
            sim = statistics.median(d[ph]["sim_pct"] for r in runs.values() for d in r if "error" not in d
                                    for ph in ("armed", "test"))
            print(f"median of {a.repeat}: dyno ui idle/ARMED {med['ui']['armed']:.1f} %, test {med['ui']['test']:.1f} % "
                  f"(the UI's own share {med['ui']['armed'] - med['bare']['armed']:.1f} % / "
                  f"{med['ui']['test'] - med['bare']['test']:.1f} %; session alone {med['bare']['armed']:.1f} % / "
                  f"{med['bare']['test']:.1f} %); the simulated rig's own cost, subtracted: {sim:.1f} %")
            print(f"median of {a.repeat}: dyno ui with the rig's blocking bus I/O (transfers in the poller's I/O "
                  f"thread) idle/ARMED {med['ui-rigio']['armed']:.1f} %, test {med['ui-rigio']['test']:.1f} %, "
                  f"ended at rest {med['ui-rigio']['ended']:.1f} % (bus read on the loop: {med['ui']['ended']:.1f} %)")
        if a.cpu_only:
            return
        print(f"poll-interval jitter, simulated rig {pace}, target period {1e3 / 150:.3f} ms "
              f"(150 Hz), {seconds:g} s after GO each:")
        bare = asyncio.run(_bare(seconds, tmp / "bare", speed))
        print(fmt_timing("without UI", bare))
        if a.quick:
            print(f"{'with UI (80x24)':<26} left out by --quick (the run with the overlay is this one's path and more)")
        else:
            ui = asyncio.run(_with_ui(seconds, tmp / "ui", overlay=False, speed=speed))
            print(fmt_timing("with UI (80x24)", ui))
        ov = asyncio.run(_with_ui(seconds, tmp / "ov", overlay=True, speed=speed))
        print(fmt_timing("with UI + model overlay", ov) + f"  overlay: {ov.get('overlay_tier') or 'pending'}")

        from dyno.app import RunOptions, run_test
        from dyno.control.controller import TestPlan

        run_dir = tmp / "replay_run"
        run_test(RunOptions(sim=True, out_dir=run_dir, plan=replace(TestPlan(), max_points=3)))
        print("\nentry points (fresh interpreter, headless, until the first screen is drawn):")
        for which, arg in (("ui", str(tmp / "st_ui")), ("calibrate", str(tmp / "st_cal.csv")),
                           ("replay", str(run_dir))):
            r = startup(which, arg)
            if "error" in r:
                print(f"  dyno {which:<10} ERROR {r['error']}")
                continue
            print(f"  dyno {which:<10} start-up {r['startup_s']:5.2f} s   peak RSS {r['peak_rss_mb']:6.1f} MB   "
                  f"belt solver imported: {r['bvp_imported']}")


if __name__ == "__main__":
    main()
