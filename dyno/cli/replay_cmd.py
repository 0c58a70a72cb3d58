"""dyno replay: re-process a logged run (opens the viewer; --json stays headless)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path


def add_arguments(p) -> None:
    p.add_argument("run", type=Path, nargs="+", help="run directory (several to overlay in the viewer)")
    p.add_argument("--calibration", type=Path, default=None, help="re-process with this calibration history")
    p.add_argument("--engine-map", type=Path, default=None, help="re-process with this engine map")
    p.add_argument("--json", action="store_true", help="print the points as one JSON document, no viewer")
    p.add_argument("--driven-loss", type=Path, default=None, metavar="FILE",
                   help="with --json: add a coast-down's driven-side loss (driven_loss.json) back to each point's "
                        "efficiency as extra keys, uncertainty propagated")


def run(args) -> int:
    from dyno.app import public_point
    from dyno.replay import replay

    if not args.json and importlib.util.find_spec("dyno.ui.replay_app") is not None:
        from dyno.runlog.reader import load_run
        from dyno.ui.replay_app import main as viewer

        for r in args.run:  # a bad path or run is one line here, before the screen is taken over
            load_run(r, with_events=False)

        return viewer(args)
    results = [replay(r, args.calibration, args.engine_map) for r in args.run]
    if args.json:
        loss = None
        if getattr(args, "driven_loss", None) is not None:
            from dyno.analysis.coastdown import load_driven_loss

            loss = load_driven_loss(args.driven_loss)

        def pub(p):
            out = public_point(p)
            if loss is not None:
                from dyno.analysis.coastdown import driven_loss_keys

                out.update(driven_loss_keys(out, loss))
            return out

        docs = [{"run_dir": r["run_dir"], "points": [pub(p) for p in r["points"]],
                 "stop": r["stop"], "aborts": r["aborts"], "torn": r["torn"],
                 **({"drive_grid": r["drive_grid"]} if "drive_grid" in r else {})} for r in results]
        print(json.dumps(docs[0] if len(docs) == 1 else docs, indent=1, default=str))
        return 0
    from dyno.cli.run_cmd import _print_table

    for r in results:
        _print_table({"run_dir": r["run_dir"], "state": (r["stop"] or {}).get("exit_status", "killed?"),
                      "reason": (r["stop"] or {}).get("reason", "no stop document"),
                      "points": [public_point(p) for p in r["points"]],
                      "frames": {"read": "-", "accepted": "-", "rejected": "-"}, "events_lost": "-",
                      "aborts": r["aborts"]})
    return 0
