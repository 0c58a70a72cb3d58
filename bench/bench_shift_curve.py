"""Benchmark: a full predicted shift curve (50 load points) with the
closed-form belt relations (target < 1 s).  Prints, never asserts.

    python bench/bench_shift_curve.py [--points 50] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    from dyno.tuning.shift_curve import EngineMap, load_engine_map, predict_shift_curve
    from dyno.tuning.tune import load_tune

    tune = load_tune(ROOT / "calibration/tunes/cvtech-stock.toml")
    maps = sorted((ROOT / "calibration/engine_maps").glob("*.csv"))
    engine = load_engine_map(maps[0]) if maps else EngineMap(
        (1500, 1900, 2400, 2800, 3200, 3500, 3700, 3850), (15.2, 16.9, 18.6, 18.2, 17.2, 15.4, 9.0, 0.0))
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        curve = predict_shift_curve(tune, engine, n_points=args.points, with_stops=False)
        times.append(time.perf_counter() - t0)
    n = sum(p.segment == "shifting" for p in curve.points)
    print(f"closed form: {n} load points, best {min(times):.3f} s, mean {sum(times) / len(times):.3f} s "
          f"(target < 1 s)")
    print("full belt model (BVP): not benchmarked here -- dyno.model does not yet export a public "
          "point solver for it; see docs/tuning.md")


if __name__ == "__main__":
    main()
