"""dyno export: a run's points and raw streams as CSV."""

from __future__ import annotations

from pathlib import Path


def add_arguments(p) -> None:
    p.add_argument("run", type=Path, help="run directory")
    p.add_argument("--out", type=Path, default=None, help="output directory (default RUN/export)")
    p.add_argument("--calibration", type=Path, default=None)
    p.add_argument("--engine-map", type=Path, default=None)


def run(args) -> int:
    from dyno.replay import export

    for path in export(args.run, args.out, calibration_path=args.calibration, engine_map_path=args.engine_map):
        print(path)
    return 0
