#!/usr/bin/env python3
"""Speed of the simulated rig's physics against real time.

Runs a test-like sequence on one core (pull start, idle, full throttle,
25 brake steps of 0.2 s each with 7 s settle+measure, kill) with the host's
150 Hz stepping, and prints the simulated time, the wall time, the speed-up
over real time and the sensor event rate.

    python bench/bench_sim.py [--seed S] [--dt 0.00667] [--quick]

``--quick`` (CI's smoke run) is accepted and runs the same sequence: the full bench takes a few seconds.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dyno.sim.physics import RigModel  # noqa: E402


def run_sequence(model: RigModel, dt_s: float) -> int:
    """Drive a steady-state test sequence; return the number of sensor events."""
    n_events = 0

    def run(duration_s: float) -> None:
        nonlocal n_events
        for _ in range(int(round(duration_s / dt_s))):
            n_events += len(model.step(dt_s))

    model.start_engine()
    run(3.0)
    model.throttle_frac = 1.0
    run(5.0)
    for _ in range(25):
        model.actuator_dir = 1
        run(0.2)
        model.actuator_dir = 0
        run(7.0)
        if model.truth().rpm_secondary < 1500:
            break
    model.engine_enabled = False
    model.actuator_dir = -1
    run(5.0)
    return n_events


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dt", type=float, default=1 / 150, help="host step in seconds (default 1/150)")
    ap.add_argument("--quick", action="store_true",
                    help="CI smoke run: the same as the full run, which already takes only a few seconds")
    args = ap.parse_args(argv)
    model = RigModel(seed=args.seed)
    t0 = time.perf_counter()
    n_events = run_sequence(model, args.dt)
    wall_s = time.perf_counter() - t0
    sim_s = model.t_s
    print(f"simulated {sim_s:.1f} s in {wall_s:.2f} s wall: speed-up {sim_s / wall_s:.0f}x real time "
          f"({n_events} sensor events, {n_events / sim_s:.0f} events/s, step {args.dt * 1e3:.2f} ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
