#!/usr/bin/env python3
"""The live web view's cost to the rig: poll-period jitter, drill latency and CPU, with 0 and 20 clients.

Each configuration runs ``dyno run --sim --speed 1`` in this process (the composition root the command uses,
with ``--web``'s server thread and feed attached as ``dyno run --web`` attaches them) with one fault drill,
while a separate client process holds N SSE streams on ``/api/events`` (one of them never reads: its socket
fills and its handler blocks).  Printed per configuration:

* poll period jitter: p99 of |interval - median| of the wall-clock intervals between polls in the test's
  states (and p99 lateness, interval - nominal period), ms;
* the drill's safe-state latency in true (simulated) time from its onset, against its bound
  (bench/bench_safety.py's table);
* CPU: the server's threads (every thread but the rig loop's, /proc/self/task) as % of one core, the feed's
  share of the rig loop (its listener timed), and per client; frames sent and dropped by the feed.

    python bench/bench_web.py [--quick] [--clients 20] [--rate 10] [--drills bus-lost@30,overtemp@30,...]
"""

from __future__ import annotations

from dataclasses import replace

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

from dyno.session.root import RunSpec, run_test  # noqa: E402
from dyno.cli.run_cmd import plan_named  # noqa: E402
from dyno.session.drills import parse_drill  # noqa: E402

TEST_STATES = {"warmup", "step", "settle", "measure"}

CLIENTS = textwrap.dedent(r'''
    import json, os, signal, socket, sys, threading, time
    host, port, token, n, dur = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), float(sys.argv[5])
    counts = [0] * n
    req = f"GET /api/events?token={token} HTTP/1.1\r\nHost: {host}\r\nAccept: text/event-stream\r\n\r\n".encode()
    socks = []
    def reader(k):
        s = socket.create_connection((host, port)); s.sendall(req); s.settimeout(0.5)
        end = time.monotonic() + dur
        while time.monotonic() < end:
            try:
                b = s.recv(65536)
            except socket.timeout:
                continue
            if not b:
                break
            counts[k] += b.count(b"\ndata: ")
        s.close()
    for k in range(n - 1 if n else 0):
        threading.Thread(target=reader, args=(k,), daemon=True).start()
    if n:  # the one that never reads: a small receive buffer that fills, then the server's writes wait
        s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.connect((host, port)); s.sendall(req); socks.append(s)
    def report(*_):
        print(json.dumps({"frames_per_reader": counts[: max(0, n - 1)]}), flush=True)
        os._exit(0)
    signal.signal(signal.SIGTERM, report)
    print("ready", flush=True)
    time.sleep(dur)
    report()
''')


def _ticks(path: str) -> int:
    with open(path) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])  # utime + stime (clock ticks)


def thread_cpu_s() -> tuple[float, float]:
    """(CPU s of the main thread, CPU s of every other thread) of this process."""
    hz = os.sysconf("SC_CLK_TCK")
    main = other = 0
    me = threading.main_thread().native_id
    for tid in os.listdir("/proc/self/task"):
        try:
            t = _ticks(f"/proc/self/task/{tid}/stat")
        except OSError:
            continue
        if int(tid) == me:
            main += t
        else:
            other += t
    return main / hz, other / hz


def run_config(n_clients: int, drill: str, *, rate_hz: float, web: bool, out: Path, speed: float = 1.0) -> dict:
    from dyno.web.feed import LiveFeed, RunSource
    from dyno.web.live import start_live_server

    feed = server = clients = None
    feed_s = [0.0]
    polls: list = []
    if web:
        feed = LiveFeed(None, rate_hz=rate_hz)
        server, _hub = start_live_server(feed, "127.0.0.1:0")
    opts = RunSpec(sim=True, speed=speed, out_dir=out, plan=plan_named("speed-hold"), drills=[parse_drill(drill)],
                      seed=3)
    wall = time.perf_counter

    def setup(ctx) -> None:
        import asyncio

        loop = asyncio.get_running_loop()
        if feed is not None:
            feed.source = RunSource(ctx, loop, speed)
            feed.loop = loop
            inner = feed.on_poll

            def timed(events, now_s):
                t0 = wall()
                inner(events, now_s)
                feed_s[0] += wall() - t0
            ctx.poller.listeners.append(timed)
        c = ctx.controller
        ctx.poller.listeners.append(lambda events, now_s: polls.append((wall(), c.state.value,
                                                                        ctx.poller.poll_period_s)))

    opts = replace(opts, setup=setup)
    if web and n_clients:
        clients = subprocess.Popen([sys.executable, "-c", CLIENTS, "127.0.0.1", str(server.port), server.token,
                                    str(n_clients), "600"], stdout=subprocess.PIPE, text=True)
        assert clients.stdout.readline().strip() == "ready"
    cpu0, t0 = thread_cpu_s(), time.monotonic()
    result = run_test(opts)
    cpu1, wall_s = thread_cpu_s(), time.monotonic() - t0
    reader_frames = None
    if clients is not None:
        clients.terminate()
        out_text, _ = clients.communicate(timeout=10)
        reader_frames = json.loads(out_text.strip().splitlines()[-1])["frames_per_reader"]
    if server is not None:
        server.stop()
    iv = [(b[0] - a[0], a[2]) for a, b in zip(polls, polls[1:]) if a[1] in TEST_STATES and b[1] in TEST_STATES]
    d = np.array([x for x, _ in iv])
    nominal = np.array([p for _, p in iv]) / speed  # the poll period in wall time
    med = float(np.median(d)) if d.size else float("nan")
    ab = result["aborts"][0] if result["aborts"] else {}
    return {"clients": n_clients, "web": web, "drill": drill, "wall_s": wall_s, "polls": int(d.size),
            "jitter_p99_ms": float(np.percentile(np.abs(d - med), 99) * 1e3) if d.size else None,
            "late_p99_ms": float(np.percentile(d - nominal, 99) * 1e3) if d.size else None,
            "cause": ab.get("cause"), "latency_s": ab.get("latency_s"),
            "server_cpu_pct": 100 * (cpu1[1] - cpu0[1]) / wall_s, "loop_cpu_pct": 100 * (cpu1[0] - cpu0[0]) / wall_s,
            "feed_cpu_pct": 100 * feed_s[0] / wall_s,
            "frames": feed.published if feed else 0, "dropped": feed.dropped if feed else 0,
            "rig_safe": result.get("rig_safe"),
            # frames each reading client got (the one never reading does not hold them up)
            "reader_frames_min": min(reader_frames) if reader_frames else None}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="CI's smoke run: one drill 2 s into the warm-up at --speed 4, the server with 0 and 3 clients (not the figures)")
    ap.add_argument("--speed", type=float, default=1.0, help="simulation pace (default 1: real time, as specified)")
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--rate", type=float, default=10.0, help="frames per second the feed publishes (default 10)")
    ap.add_argument("--drills", default="bus-lost@30,overtemp@30,adc-error@30")
    ap.add_argument("--repeat", type=int, default=1,
                    help="run every configuration this many times, interleaved (the summary takes the medians: a "
                         "shared machine's jitter moves between runs of the same configuration)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    from bench_safety import DRILLS

    drills = ["bus-lost@warmup+2"] if a.quick else a.drills.split(",")
    n = 3 if a.quick else a.clients
    configs = [(True, 0), (True, n)] if a.quick else [(False, 0), (True, 0), (True, n)]
    speed = 4.0 if a.quick else a.speed
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        runs = [(rep, drill, k, cfg) for rep in range(max(1, a.repeat)) for drill in drills
                for k, cfg in enumerate(configs)]
        for rep, drill, k, (web, nc) in runs:
            row = run_config(nc, drill, rate_hz=a.rate, web=web, out=Path(tmp) / f"{drill}-{k}-{rep}", speed=speed)
            bound = DRILLS.get(drill.split("@")[0], (None, None))[1]
            row["bound_s"] = bound
            row["within_bound"] = bound is None or (row["latency_s"] is not None and row["latency_s"] <= bound)
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    if a.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"dyno run --sim --speed {speed:g}, feed at {a.rate:g} frames/s, clients in another process (one never reads)")
    print("| drill | server | clients | polls | jitter p99 ms | late p99 ms | latency s (bound) | server CPU % "
          "| feed on loop % | frames (dropped) | least frames a reader got |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        lat = "-" if r["latency_s"] is None else f"{r['latency_s']:.3f}"
        print(f"| {r['drill']} | {'yes' if r['web'] else 'no'} | {r['clients']} | {r['polls']} | {r['jitter_p99_ms']:.2f} "
              f"| {r['late_p99_ms']:.2f} | {lat} ({r['bound_s']}) {'ok' if r['within_bound'] else 'OUT'} "
              f"| {r['server_cpu_pct']:.2f} | {r['feed_cpu_pct']:.2f} | {r['frames']} ({r['dropped']}) "
              f"| {'-' if r['reader_frames_min'] is None else r['reader_frames_min']} |")
    for drill in drills:
        by = {}
        for key in {(r["web"], r["clients"]) for r in rows if r["drill"] == drill}:
            rs = [r for r in rows if r["drill"] == drill and (r["web"], r["clients"]) == key]
            by[key] = {f: statistics.median(r[f] for r in rs) for f in ("jitter_p99_ms", "server_cpu_pct")}
        base, zero, many = by.get((False, 0), by[(True, 0)]), by[(True, 0)], by[(True, n)]
        per_client = (many["server_cpu_pct"] - zero["server_cpu_pct"]) / max(1, n)
        print(f"{drill}: jitter p99 {zero['jitter_p99_ms']:.2f} ms with 0 clients -> {many['jitter_p99_ms']:.2f} ms "
              f"with {n} (rise {many['jitter_p99_ms'] - zero['jitter_p99_ms']:+.2f} ms; no server "
              f"{base['jitter_p99_ms']:.2f}); server {zero['server_cpu_pct']:.2f} % of a core idle, "
              f"{per_client:.3f} % per client" + (f" (medians of {a.repeat})" if a.repeat > 1 else ""))
    bad = [r for r in rows if not r["within_bound"]]
    print(f"{len(rows) - len(bad)}/{len(rows)} drills within their bound")
    return 0


if __name__ == "__main__":
    sys.exit(main())
