#!/usr/bin/env python3
"""The live screen at 80x24, as text: before GO and after the test is done (Textual's pilot, in process).

Run:  python bench/ui_screens.py [--speed 8] [--seed 0] [--plan speed-hold] > capture.md

Prints Markdown: the commit, the two screens in fenced blocks, and what the run directory held before the quit
(torque_zero, safety, the end record, report.html), with the events lost before GO (the screen's "lost" row)
beside the simulated Nano's own drop counter.
"""

from __future__ import annotations

import argparse
import asyncio
import datetime as dt
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent).stdout.strip() or "?"
    except OSError:
        return "?"


async def _capture(speed: float, seed: int, plan_name: str, run_dir: Path) -> dict:
    from dyno.control.api import State
    from dyno.control.plans import plan_named
    from dyno.ui.live_app import LiveApp
    from dyno.ui.session import LiveOptions
    from tests.screens import screen_text, wait_for

    app = LiveApp(LiveOptions(sim=True, speed=speed, seed=seed, out_dir=run_dir, plan=plan_named(plan_name)))
    out: dict = {}
    async with app.run_test(size=(80, 24)) as pilot:
        assert await wait_for(pilot, lambda: app.session is not None
                              and app.session.controller.state is State.ARMED, 120), "never armed"
        s = app.session
        await pilot.pause(2.0)
        app.refresh_values(force=True)
        await pilot.pause(0.3)
        out["armed"] = screen_text(app)
        out["lost_before_go"] = s.poller.reader.events_lost
        out["dropped_true_before_go"] = s.sim.firmware.events_dropped
        await pilot.press("g")
        assert await wait_for(pilot, lambda: "Start the test?" in screen_text(app), 5)
        out["go_dialog"] = screen_text(app)
        await pilot.press("y")
        t0 = time.monotonic()
        assert await wait_for(pilot, lambda: s.controller.state in (State.DONE, State.ABORTED), 900), s.controller.reason
        assert await wait_for(pilot, lambda: (run_dir / "report.html").is_file(), 180), "no report.html"
        out["wall_s"] = time.monotonic() - t0
        await pilot.pause(1.5)
        app.refresh_values(force=True)
        await pilot.pause(0.3)
        out["done"] = screen_text(app)
        docs = [json.loads(x) for x in (run_dir / "documents.jsonl").read_text().splitlines() if x.strip()]
        out["types"] = [d["type"] for d in docs if d["type"] in ("torque_zero", "safety", "stop")]
        out["zero"] = next((d for d in docs if d["type"] == "torque_zero"), None)
        out["points"] = len(s.controller.points)
        out["skipped"] = list(getattr(s.controller, "skips", []))
        await pilot.press("q")
        await pilot.pause(0.5)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speed", type=float, default=8.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--plan", default="speed-hold")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = asyncio.run(_capture(args.speed, args.seed, args.plan, Path(tmp) / "run"))
    zc = out["zero"] or {}
    print(f"# `dyno ui --sim` at 80x24: before GO and after the test ({dt.date.today().isoformat()})\n")
    print(f"Commit {_commit()}; `python bench/ui_screens.py --speed {args.speed:g} --seed {args.seed} --plan "
          f"{args.plan}` (Textual's pilot, in process: the screen as the app renders it).\n")
    print(f"- events lost before GO: {out['lost_before_go']} on the screen, {out['dropped_true_before_go']} "
          "dropped by the simulated Nano's ring (its own counter)")
    print(f"- the run directory before the quit: {', '.join(out['types'])} records, report.html; "
          f"{out['points']} points; the test and its report took {out['wall_s']:.0f} s of wall time")
    for why in out["skipped"]:
        print(f"- skipped: {why}")
    if zc:
        print(f"- torque zero after the test: {zc['after']['torque_nm']:+.3f} ± {zc['after']['ci95_nm']:.3f} N·m "
              f"(before GO {zc['before']['torque_nm']:+.3f}), drift {zc['drift_nm']:+.3f} ± "
              f"{zc['drift_ci95_nm']:.3f} N·m, flagged {zc['flagged']}")
    for title, key in (("ARMED, before GO", "armed"), ("GO asks (the plan's words)", "go_dialog"),
                       ("DONE, the screen left up", "done")):
        print(f"\n## {title}\n\n```text\n{out[key]}\n```")
    return 0


if __name__ == "__main__":
    sys.exit(main())
