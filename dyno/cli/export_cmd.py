"""dyno export: a run's points and raw streams as CSV (a directory), Parquet or ASAM MDF4 (one file)."""

from __future__ import annotations

import sys
from pathlib import Path

SUFFIX = {"parquet": ".parquet", "mdf4": ".mf4"}


def add_arguments(p) -> None:
    p.add_argument("run", type=Path, help="run directory")
    p.add_argument("--format", choices=("csv", "parquet", "mdf4"), default="csv",
                   help="csv (default: a directory of CSV files), parquet (pyarrow) or mdf4 (asammdf): one file; "
                        "parquet and mdf4 need the optional extra: pip install 'dyno[export]'")
    p.add_argument("--out", type=Path, default=None,
                   help="csv: output directory (default RUN/export); parquet/mdf4: the file (default "
                        "RUN/export/<run>.parquet or .mf4)")
    p.add_argument("--calibration", type=Path, default=None,
                   help="torque calibration history CSV (default: the one the run used)")
    p.add_argument("--engine-map", type=Path, default=None, help="engine map CSV (default: the run's engine_map.csv)")


def run(args) -> int:
    if args.format == "csv":
        from dyno.runlog.replay import export

        for path in export(args.run, args.out, calibration_path=args.calibration, engine_map_path=args.engine_map):
            print(path)
        return 0
    import importlib.util

    module = {"parquet": "pyarrow", "mdf4": "asammdf"}[args.format]
    if importlib.util.find_spec(module) is None:  # say so before reading anything
        from dyno.library.exports import MissingExtra

        print(f"dyno export: error: {MissingExtra(args.format, module)}", file=sys.stderr)
        return 2
    from dyno.errors import ConfigError
    from dyno.fileio import write_atomic
    from dyno.library import exports
    from dyno.runlog.replay import replay
    from dyno.runlog.reader import load_run

    result = replay(args.run, calibration_path=args.calibration, engine_map_path=args.engine_map)
    run_ = load_run(args.run)
    out = args.out or Path(args.run) / "export" / f"{Path(args.run).resolve().name}{SUFFIX[args.format]}"
    if out.is_dir():
        raise ConfigError(out, "--out", f"a file path for --format {args.format} (it is a directory)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.stem}.tmp{SUFFIX[args.format]}")  # asammdf insists on its suffix
    written = tmp
    try:
        try:
            written = Path(getattr(exports, f"write_{args.format}")(run_, result["points"], tmp))
        except exports.MissingExtra as exc:
            print(f"dyno export: error: {exc}", file=sys.stderr)
            return 2
        write_atomic(out, written.read_bytes())  # readers never see half a file
    finally:
        for t in {tmp, written}:
            t.unlink(missing_ok=True)
    print(out)
    return 0
