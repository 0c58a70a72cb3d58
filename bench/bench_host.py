#!/usr/bin/env python3
"""Host benchmarks: decode+check+log throughput, simulation speed-up, and false
accepts of corrupted frames, v1 (CRC-16) against v2 (CRC-32C), at bit-error rates
1e-4 .. 1e-2 (plus 2e-2, 5e-2), with v2's computed expectation beside the count.

Run:  python bench/bench_host.py [--frames N] [--quick] [--fuzz-only]
Prints figures; asserts nothing (the machine is shared and noisy).
``--quick`` (CI's smoke run): 10^4 frames per rate, 2*10^4 for the throughput, and a short simulated test
(about 6 points of at most 3 s each) for the speed-up.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dyno.acquisition.streams import Streams  # noqa: E402
from dyno.protocol import v1, v2  # noqa: E402
from dyno.protocol.session import LinkSession  # noqa: E402
from dyno.runlog.writer import RunWriter  # noqa: E402


def realistic_frames(n: int, seed: int = 0, version: int = 1) -> list[bytes]:
    """Frames as the device builds them at 150 Hz polling of a 63/127/125 Hz event mix."""
    proto = v2 if version == 2 else v1
    rng = np.random.default_rng(seed)
    frames, t, seq = [], 1_000_000, 0
    for _ in range(n):
        events = []
        for _ in range(int(rng.integers(0, 4))):
            t += int(rng.integers(500, 4000))
            ch = int(rng.choice([1, 2, 3], p=[0.2, 0.4, 0.4]))
            events.append(v1.Event(ch, t & 0xFFFFFFFF, int(rng.integers(30000, 42000)) if ch == 3 else 0,
                                   5 if ch == 3 else 0))
        k = proto.fit_events(events)
        if version == 2:
            frames.append(v2.encode_data_frame(seq, 0x10, 0x2BC6, 0, events[:k], t))
        else:
            frames.append(v1.encode_data_frame(seq, 0, 0, events[:k], t))
        seq = (seq + 1) & 0xFF
        t += 2000
    return frames


def bench_throughput(n: int) -> float:
    frames = realistic_frames(n, version=2)  # the protocol the host session speaks (v2)
    session = LinkSession()
    streams = Streams()
    with tempfile.TemporaryDirectory() as d:
        writer = RunWriter(Path(d) / "run", {"mode": "bench"})
        from dyno.acquisition.reader import Unwrapper

        unwrap = Unwrapper()
        t0 = time.process_time()
        for raw in frames:
            fr = session.accept(raw)
            if fr is not None:
                evs = [v1.Event(e.channel, unwrap(e.t_us), e.code, e.status) for e in fr.events]
                streams.extend(evs)
                writer.events(evs)
        dt = time.process_time() - t0
        writer.close("success")
    return n / dt


def false_accepts(frames: list[bytes], ber: float, seed: int, version: int = 1) -> dict:
    """Deliver every frame once through a bit-error channel (each bit flipped with
    probability ``ber``) to a session expecting exactly that frame next.

    A false accept is a delivery whose bytes differ from what was sent and which
    the session still accepts (CRC, structure and sequence checks all passed).
    Only corrupted deliveries go through the session (an intact one is accepted by
    construction); the flips are drawn in blocks.
    """
    rng = np.random.default_rng(seed)
    corrupted = false_acc = 0
    causes: dict = {}
    block = 20_000
    for start in range(0, len(frames), block):
        chunk = frames[start:start + block]
        flips = np.packbits(rng.random((len(chunk), 256)) < ber, axis=1)
        hit = np.flatnonzero(flips.any(axis=1))
        for i in hit:
            raw = chunk[i]
            got = (np.frombuffer(raw, dtype=np.uint8) ^ flips[i]).tobytes()
            corrupted += 1
            session = LinkSession(version)
            session.last_seq = (raw[3] - 1) & 0xFF  # the host accepted the previous frame
            prev = frames[start + i - 1] if start + i else None
            session.last_accepted = prev[: prev[1]] if prev else None
            if version == 2:  # ... of this boot
                session.boot_id = raw[5] << 8 | raw[6]
                session.reset_cause = raw[4] >> 4
            if session.accept(got) is not None:  # one foreign-looking read never raises
                false_acc += 1
            for k, v in session.stats.rejected.items():
                causes[k] = causes.get(k, 0) + v
    return {"ber": ber, "frames": len(frames), "corrupted": corrupted, "false_accepts": false_acc,
            "rejected": causes}


def bench_sim(seconds_cap: float = 600.0, plan=None) -> dict:
    from dyno.session.root import RunSpec, run_test

    kw = {} if plan is None else {"plan": plan}
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        c0 = time.process_time()
        r = run_test(RunSpec(sim=True, seed=0, out_dir=Path(d) / "r", max_sim_s=seconds_cap, **kw))
        wall = time.perf_counter() - t0
        cpu = time.process_time() - c0
    return {"sim_s": r["sim_time_s"], "wall_s": wall, "cpu_s": cpu, "points": len(r["points"]),
            "speedup_wall": r["sim_time_s"] / wall, "speedup_cpu": r["sim_time_s"] / cpu}


def expected_false_accepts_v2(frames: list[bytes], ber: float) -> float:
    """Upper bound on v2's expected false accepts (docs/protocol.md): a frame of n bits gets
    through only with >= 6 flipped bits (CRC-32C's Hamming distance at these lengths) or a
    hit length byte (the check then covers another span), and then with probability 2**-32."""
    from math import comb

    total = 0.0
    for n_bytes in {raw[1] for raw in frames}:
        n = 8 * n_bytes
        p_ge6 = 1.0 - sum(comb(n, k) * ber**k * (1 - ber) ** (n - k) for k in range(6))
        p_len = 1.0 - (1 - ber) ** 8
        share = sum(1 for raw in frames if raw[1] == n_bytes)
        total += share * (p_ge6 + p_len) * 2.0**-32
    return total


def fuzz(n_fa: int, bers=(1e-4, 1e-3, 3e-3, 1e-2, 2e-2, 5e-2)) -> None:
    print(f"false accepts over {n_fa:,} fault-injected frames per bit-error rate "
          f"(v2: expected count computed beside it):")
    print(f"{'BER':>8} {'ver':>3} {'corrupted':>10} {'false_acc':>9} {'expected':>9}  rejections by cause")
    frames = {ver: realistic_frames(n_fa, seed=1, version=ver) for ver in (1, 2)}
    for i, ber in enumerate(bers):
        for ver in (1, 2):
            r = false_accepts(frames[ver], ber, seed=100 + i, version=ver)
            exp = f"{expected_false_accepts_v2(frames[2], ber):9.1e}" if ver == 2 else f"{'':>9}"
            print(f"{ber:>8.0e} {'v' + str(ver):>3} {r['corrupted']:>10,} {r['false_accepts']:>9} {exp}  "
                  f"{r['rejected']}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=1_000_000, help="frames per bit-error rate")
    ap.add_argument("--quick", action="store_true",
                    help="10^4 frames per rate, short throughput run, a short simulated test (CI smoke run)")
    ap.add_argument("--fuzz-only", action="store_true", help="only the false-accept fuzz")
    ap.add_argument("--bers", default="1e-4,1e-3,3e-3,1e-2,2e-2,5e-2", help="bit-error rates to fuzz")
    args = ap.parse_args()
    n_fa = 10_000 if args.quick else args.frames
    print(f"# host benchmarks (pid {os.getpid()}, {os.cpu_count()} cpus)")
    bers = tuple(float(x) for x in args.bers.split(","))
    if args.fuzz_only:
        fuzz(n_fa, bers)
        return
    fps = bench_throughput(20_000 if args.quick else 200_000)
    print(f"decode+check+unwrap+stream+log: {fps:,.0f} frames/s per core "
          f"({fps / 150:.0f}x the 150 Hz poll rate)")
    if args.quick:
        from dataclasses import replace

        from dyno.control.api import TestPlan

        s = bench_sim(plan=replace(TestPlan(), target_points=6, max_measure_s=3.0, warmup_s=2.0))
    else:
        s = bench_sim()
    print(f"simulated {'short (--quick)' if args.quick else 'full'} test: {s['points']} points, "
          f"{s['sim_s']:.0f} s simulated in {s['wall_s']:.1f} s wall "
          f"({s['cpu_s']:.1f} s cpu): speed-up {s['speedup_wall']:.1f}x wall, {s['speedup_cpu']:.1f}x cpu")
    fuzz(n_fa, bers)


if __name__ == "__main__":
    main()
