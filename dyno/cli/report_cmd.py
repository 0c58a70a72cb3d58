"""dyno report: (re)build a run's report.html (simulated, real-rig or imported legacy runs)."""

from __future__ import annotations

import sys
from pathlib import Path


def add_arguments(p) -> None:
    p.add_argument("run", type=Path, nargs="+", help="run directory (several: one report each)")
    p.add_argument("--out", type=Path, default=None,
                   help="where to write the page (one run only; default RUN/report.html)")
    p.add_argument("--model", choices=("auto", "full"), default="auto",
                   help="belt-model overlay: auto = the full model if already cached, else its closed form "
                        "(instant); full = solve the full model (seconds per point, cached)")


def run(args) -> int:
    from dyno.errors import ConfigError
    from dyno.report.writer import write_report

    if args.out is not None and len(args.run) > 1:
        raise ConfigError(args.out, "--out", "one run directory with --out (several runs: one report each)")
    if args.out is not None and not args.out.parent.is_dir():
        raise ConfigError(args.out, "--out", f"a file in an existing directory ({args.out.parent} does not exist)")
    for run_dir in args.run:
        try:
            path = write_report(run_dir, args.out, full_model=args.model == "full")
        except OSError as exc:  # a read-only run directory, a full disk: one line, the run itself untouched
            print(f"dyno report: {run_dir}: report not written: {exc}", file=sys.stderr)
            return 1
        print(path, flush=True)
    return 0
