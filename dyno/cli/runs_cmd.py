"""dyno runs: list and filter the run library; ``dyno runs reindex [DIR]`` rebuilds its index."""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import sys
from pathlib import Path


def _date(text: str) -> str:
    try:
        return _dt.date.fromisoformat(text).isoformat()
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a date YYYY-MM-DD, got {text!r}") from None


def add_arguments(p) -> None:
    p.add_argument("action", nargs="?", choices=("list", "reindex"), default="list",
                   help="list (default) or reindex: rebuild the index from the run directories")
    p.add_argument("dir", nargs="?", type=Path, default=None,
                   help="the runs directory (default: $DYNO_RUNS_DIR, else runs/)")
    p.add_argument("--json", action="store_true", help="one JSON document: the runs (and their points with --points)")
    p.add_argument("--points", action="store_true", help="with --json: include each run's points")
    p.add_argument("--tune", default=None, metavar="NAME", help="only runs of this tune (name or sha256 prefix)")
    p.add_argument("--since", type=_date, default=None, metavar="YYYY-MM-DD", help="only runs from this date on (UTC)")
    p.add_argument("--state", default=None, metavar="S",
                   help="only runs that ended in this state (done, aborted, incomplete) or exit status (success, abort)")


def run(args) -> int:
    from dyno.library import index as lib

    root = args.dir if args.dir is not None else lib.runs_dir()
    if args.dir is not None and not args.dir.is_dir():
        from dyno.errors import ConfigError

        raise ConfigError(args.dir, "DIR", "an existing runs directory")

    def warn(line: str) -> None:
        print(f"dyno runs: {line}", file=sys.stderr)

    conn = lib.open_library(root, warn=warn)
    try:
        if args.action == "reindex":
            n = lib.reindex(conn, root)
            print(f"{root / lib.INDEX_NAME}: {n} runs indexed")
            return 0
        lib.sync(conn, root)  # runs added, changed or removed since (the directories are the truth)
        rows = lib.query(conn, tune=args.tune, since=args.since, state=args.state)
        from dyno.library.advice import advised_vs_measured

        for r in rows:  # a run on a tune dyno tune advise proposed: its prediction beside the measurement
            adv = advised_vs_measured(root, r)
            if adv is not None:
                r["advised"] = adv
        if args.json:
            for r in rows:
                r.pop("files_sig", None)
                r["plan"] = json.loads(r.pop("plan_json")) if r.get("plan_json") else None
                if args.points:
                    r["points"] = lib.points_of(conn, r["path"])
            print(json.dumps({"index": str(root / lib.INDEX_NAME), "runs": rows}, indent=1))
        else:
            _print_table(rows)
    finally:
        conn.close()
    return 0


def _clip(text: str, width: int) -> str:
    """At most ``width`` characters, cut in the middle: an advised tune's name ends in the parts changed."""
    if len(text) <= width:
        return text
    head = (width - 1) // 2
    return text[:head] + "…" + text[-(width - 1 - head):]


def _print_table(rows: list[dict]) -> None:
    print(f"{'created (UTC)':<20} {'run':<24} {'tune':<30} {'state':<10} {'abort':<10} {'pts':>4} "
          f"{'peak eff %':>14} {'@ rpm_s':>7}")
    for r in rows:
        eff = r["peak_efficiency"]
        peak = "-" if eff is None else f"{100 * eff:.1f} ± {100 * (r['peak_efficiency_sem'] or 0):.1f}"
        rpm = "-" if r["peak_efficiency_rpm_secondary"] is None else f"{r['peak_efficiency_rpm_secondary']:.0f}"
        print(f"{(r['created_utc'] or '-'):<20} {r['name'][:24]:<24} {_clip(r['tune_name'] or '-', 30):<30} "
              f"{r['state'][:10]:<10} {(r['abort_cause'] or '')[:10]:<10} {r['n_points']:>4} {peak:>14} {rpm:>7}")
        if r.get("advised"):
            from dyno.library.advice import format_line

            print(f"    {format_line(r['advised'])}")
    print(f"{len(rows)} runs")
