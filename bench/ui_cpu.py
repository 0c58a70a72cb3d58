"""bench/bench_ui.py's CPU part: the live screen (or the session alone) in a real pseudo-terminal, as its own
process, its CPU per phase (idle/ARMED, a test, at rest after it) with the simulated rig's own cost apart."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


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


CLIENT = '''
import socket, sys
host, port, query = sys.argv[1], int(sys.argv[2]), sys.argv[3]
s = socket.create_connection((host, port))
s.sendall(f"GET /api/events?{query} HTTP/1.1\\r\\nHost: {host}\\r\\nAccept: text/event-stream\\r\\n\\r\\n".encode())
while s.recv(65536):
    pass
'''


def web_view():  # the live web view as dyno ui --web serves it, and one page reading its stream (another process)
    import argparse, subprocess
    from dyno.web.attach import WebView
    web = WebView.start("dyno ui", argparse.Namespace(web="127.0.0.1:0", web_stop=False))
    url = web.server.url[len("http://"):]
    hostport, _, query = url.partition("/?")
    host, _, port = hostport.rpartition(":")
    client = subprocess.Popen([sys.executable, "-c", CLIENT, host, port, query], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    return web, client


async def main():
    from dyno.ui.session import LiveOptions
    opts = LiveOptions(sim=True, speed=speed, out_dir=out_dir)
    if mode in ("ui", "ui-web"):
        from dyno.ui.live_app import LiveApp
        web = client = None
        if mode == "ui-web":
            from dyno.cli.ui_cmd import _with_web
            web, client = web_view()
            app = _with_web(LiveApp, web)(opts)
        else:
            app = LiveApp(opts)
        task = asyncio.get_running_loop().create_task(drive(lambda: app.session, app._quit))
        await app.run_async()
        await task
        if web is not None:
            client.kill()
            web.end()
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
