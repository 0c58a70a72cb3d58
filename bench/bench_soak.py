#!/usr/bin/env python3
"""Soak: back-to-back runs of every shipped plan on the simulated rig, for simulated hours, in ONE process.

Each run is ``dyno run --sim`` in-process (``dyno.session.root.run_test``, the composition root the command uses,
signal handlers included) as fast as the machine goes (``speed=None``), with 1 % mixed transfer faults,
the plans in turn, a new seed each run.  Every ``--drill-every-min`` simulated minutes the next run gets
one random drill (``dyno.session.drills``) at a random phase or time; the run after it starts only once the safe
state's release stroke has ended (``run_test`` awaits ``finish_release``), as an operator re-arms.
The signal drills (sigint/sigterm/sighup) are included and run in this process: the run's own handlers
(``handle_signals=True``, as ``dyno run`` installs them) turn them into a ``signal`` abort, and the
process must go on — which is part of what is soaked.

After every run: the points replayed from its directory (``dyno.runlog.replay.replay``) against its own, the run
indexed in the run library (``index_after_run``, as ``dyno run`` does) and, after every abort, the brake
pads off the rotor as the physics has them (``outputs.pads_off_rotor``, ``rig_safe`` and the model itself).
Per simulated hour (``--report-min``) one line: runs, points, aborts by cause, unhandled exceptions,
RSS, open file descriptors, run directories vs library entries, replay mismatches, brake violations,
events lost — flushed as it comes, so a soak that is stopped still leaves its figures.

    python bench/bench_soak.py [--hours 8] [--quick] [--json] [--runs-dir DIR] [--seed S] [--plans a,b]

``--quick`` (CI's smoke run): 6 simulated minutes of the short plans (engine-hold, torque-hold, coast-down), a
report every 3, a drill every 1.5 (under a minute of wall time);
``--hours 0.5 --report-min 10`` is the CI soak (tests/e2e/test_soak_short.py).  Runs go to a temporary
runs directory (deleted at the end unless ``--runs-dir`` is given), never to the repository's ``runs/``.
Exit 0 when every acceptance check holds (docs/safety.md, "Soak"), 1 otherwise.
"""

from __future__ import annotations

from dataclasses import replace

import argparse
import json
import logging
import os
import random
import resource
import shutil
import sys
import tempfile
import threading
import time
import traceback
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

PLANS = ("speed-hold", "thesis-step", "sweep", "torque-hold", "engine-hold", "engagement", "coast-down",
         "drive-grid")
#: the drills a soak draws from (every one in dyno.session.drills; loop-stall on both sides of the loop's liveness
#: limit, ~0.236 s, and of watchdog_s)
DRILLS = ("device-reset", "hall-dead:primary", "hall-dead:secondary", "hall-dead:both", "thermometer-stuck",
          "thermometer-lost", "adc-error", "adc-stuck", "bus-lost", "overtemp", "overspeed", "loop-stall:200",
          "loop-stall:300", "loop-stall:800", "loop-freeze", "controller-crash", "disk-full", "sigint", "sigterm",
          "sighup")
#: onsets: phases of the test (dyno.session.drills.PHASES) and plain times from the first frame
ONSETS = ("armed", "warmup+1", "loaded+2", "measure+1", "after+0.5", "20", "45")
QUICK_PLANS = "engine-hold,torque-hold,coast-down"  # the shortest ones with points (~1-2 simulated min each)
RSS_GROWTH_MAX = 0.10  # the bound on RSS growth after the first hour


def rss_mb() -> float:
    """Resident set size now (VmRSS), MB; the peak from getrusage where /proc is absent."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


class Errors:
    """Unhandled exceptions wherever they surface: a run that raised, a thread, an unraisable, a logged
    ERROR (asyncio's "Task exception was never retrieved", the watchdog's logger)."""

    def __init__(self) -> None:
        self.count = 0
        self.first: list[str] = []  # the first few, for the report

    def add(self, text: str) -> None:
        self.count += 1
        if len(self.first) < 5:
            self.first.append(text[-2000:])

    def install(self) -> None:
        errors = self

        class _Handler(logging.Handler):
            def emit(self, record: logging.LogRecord) -> None:
                errors.add(f"logged {record.name}: {self.format(record)}")

        logging.getLogger().addHandler(_Handler(level=logging.ERROR))
        threading.excepthook = lambda a: self.add("thread: " + "".join(
            traceback.format_exception(a.exc_type, a.exc_value, a.exc_traceback)))
        sys.unraisablehook = lambda u: self.add(f"unraisable: {u.exc_type.__name__}: {u.exc_value} ({u.object!r})")


def options(plan: str, seed: int, drill, fault_rate: float):
    from dyno.resources import DEFAULT_ENGINE_MAP
    from dyno.session.root import RunSpec
    from dyno.control.plans import plan_named

    opts = RunSpec(sim=True, seed=seed, speed=None, fault_rate=fault_rate, plan=plan_named(plan),
                      drills=[drill] if drill is not None else [], handle_signals=True)
    if plan == "drive-grid":  # its grid needs the part-throttle curves (as bench_safe_state runs it)
        opts = replace(opts, engine_map_path=DEFAULT_ENGINE_MAP.with_name("baja-10hp-representative-part-throttle.csv"))
    return opts


def physics_safe(ctx) -> bool:
    """The rig at rest and safe as the simulated world has it: pads off, actuator off, throttle idle, killed."""
    m = ctx.sim.model
    return bool(m.actuator_mm <= m.brake.a0_mm and m.actuator_dir == 0 and m.throttle_frac == 0.0
                and not m.engine_enabled)


def one_run(plan: str, seed: int, drill, fault_rate: float, errors: Errors, warns: list) -> dict:
    """One run and its checks; a small record (nothing of the run is kept: the soak must not hold memory)."""
    from dyno.session.root import run_test
    from dyno.library.index import index_after_run
    from dyno.runlog.replay import replay

    held: dict = {}
    opts = options(plan, seed, drill, fault_rate)
    opts = replace(opts, setup=lambda ctx: held.update(ctx=ctx))
    rec = {"plan": plan, "seed": seed, "drill": str(drill) if drill else None}
    try:
        r = run_test(opts)
    except Exception as exc:  # noqa: BLE001 - counted: the acceptance figure
        errors.add(f"{plan} seed {seed} {rec['drill']}: " + traceback.format_exc())
        rec.update(state="exception", sim_s=0.0, error=f"{type(exc).__name__}: {exc}")
        ctx = held.get("ctx")
        if ctx is not None and ctx.writer is not None:  # the directory it left, counted with the others
            rec["run_dir"] = str(ctx.writer.run_dir)
        return rec
    ctx = held.pop("ctx")
    if ctx.signal_received is not None and not (drill and drill.name in ("sigint", "sigterm", "sighup")):
        rec["stop"] = f"signal {ctx.signal_received} from outside"  # the run's handler took it: end the soak
    rec.update(state=r["state"], sim_s=float(r.get("sim_time_s") or 0.0), run_dir=r["run_dir"],
               points=len(r["points"]), events_lost=int(r.get("events_lost") or 0),
               cause=r["aborts"][0]["cause"] if r["aborts"] else None,
               drill_fired=bool(r.get("drills")), rig_safe=bool(r["rig_safe"]),
               heartbeat_cuts=sum(d.get("cause") == "heartbeat" for d in (r.get("supervisor") or {}).get("drops", [])),
               pads_off=bool(r["outputs"].get("pads_off_rotor")), physics_safe=physics_safe(ctx))
    del ctx
    held.clear()  # (the soak keeps no run context alive)
    rec["indexed"] = index_after_run(r["run_dir"], lambda line: warns.append(line))
    try:
        rec["replayed"] = len(replay(r["run_dir"])["points"])
    except Exception as exc:  # noqa: BLE001 - a run that does not replay is a finding
        rec["replayed"] = None
        rec["replay_error"] = f"{type(exc).__name__}: {exc}"
    return rec


def library_counts(root: Path, run_dirs: list[str]) -> tuple[int, int, int]:
    """(run directories on disk, library entries, our runs missing from the library)."""
    import sqlite3

    from dyno.library.index import INDEX_NAME, find_run_dirs, key

    on_disk = len(find_run_dirs(root))
    conn = sqlite3.connect(root / INDEX_NAME)  # read-only look; closed at once (fds must stay flat)
    try:
        paths = {row[0] for row in conn.execute("SELECT path FROM runs")}
    finally:
        conn.close()
    missing = sum(1 for d in run_dirs if key(d) not in paths)
    return on_disk, len(paths), missing


def stalls_host(drill: str | None) -> bool:
    return bool(drill) and drill.startswith(("loop-stall", "loop-freeze"))


def silences_the_nano(drill: str | None) -> bool:
    """A drill after which the Nano's heartbeat may rightly stop (the loop stalled, the link lost)."""
    return stalls_host(drill) or bool(drill) and drill.startswith("bus-lost")


class Interval:
    """The counters of one report interval."""

    def __init__(self) -> None:
        self.runs = self.points = self.exceptions = self.events_lost = self.points_lost = 0
        self.unreplayable = self.unindexed = self.brake_violations = self.drills = self.drills_fired = 0
        self.events_lost_in_stalls = 0
        self.false_cuts = 0  # the Nano's heartbeat cut in a run where nothing stalled the loop or cut the link
        self.aborts: Counter = Counter()

    def add(self, rec: dict) -> None:
        self.runs += 1
        if rec["state"] == "exception":
            self.exceptions += 1
            return
        self.points += rec["points"]
        if rec.get("heartbeat_cuts") and not silences_the_nano(rec["drill"]):
            self.false_cuts += rec["heartbeat_cuts"]
        if stalls_host(rec["drill"]):  # a stalled host cannot drain the Nano's ring: lost by design, counted
            self.events_lost_in_stalls += rec["events_lost"]
        else:
            self.events_lost += rec["events_lost"]
        if rec["drill"]:
            self.drills += 1
            self.drills_fired += rec["drill_fired"]
        if rec["replayed"] is None:
            self.unreplayable += 1
        elif rec["replayed"] != rec["points"]:
            self.points_lost += abs(rec["points"] - rec["replayed"])
        self.unindexed += not rec["indexed"]
        if rec["state"] == "aborted":
            self.aborts[rec["cause"]] += 1
        # every run ends with the pads off the rotor; after an abort it is the acceptance check
        if not (rec["pads_off"] and rec["rig_safe"] and rec["physics_safe"]):
            self.brake_violations += 1


def report_row(hour: float, iv: Interval, total: Interval, wall_s: float, root: Path, run_dirs: list[str],
               errors: Errors) -> dict:
    on_disk, entries, missing = library_counts(root, run_dirs)
    return {"sim_h": round(hour, 3), "wall_s": round(wall_s, 1), "runs": iv.runs, "points": iv.points,
            "aborts": dict(sorted(iv.aborts.items())), "drills": iv.drills, "drills_fired": iv.drills_fired,
            "exceptions": errors.count, "rss_mb": round(rss_mb(), 1), "fds": open_fds(),
            "run_dirs": on_disk, "library_entries": entries, "unindexed": total.unindexed + missing,
            "unreplayable": total.unreplayable, "points_lost": total.points_lost,
            "events_lost": total.events_lost, "events_lost_in_stalls": total.events_lost_in_stalls,
            "brake_violations": total.brake_violations, "false_cuts": total.false_cuts,
            "runs_total": total.runs, "points_total": total.points}


def print_row(row: dict, out) -> None:
    aborts = ",".join(f"{k}:{v}" for k, v in row["aborts"].items()) or "-"
    print(f"[{row['sim_h']:6.2f} h sim, {row['wall_s']:7.0f} s wall] runs {row['runs']:3d} points {row['points']:4d} "
          f"aborts {aborts} drills {row['drills_fired']}/{row['drills']} | exceptions {row['exceptions']} "
          f"RSS {row['rss_mb']:.1f} MB fds {row['fds']} | run dirs {row['run_dirs']} library {row['library_entries']} "
          f"unindexed {row['unindexed']} unreplayable {row['unreplayable']} points lost {row['points_lost']} "
          f"events lost {row['events_lost']} (in loop stalls {row['events_lost_in_stalls']}) "
          f"brake violations {row['brake_violations']} false cuts {row['false_cuts']}", file=out, flush=True)


def verdict(rows: list[dict], total: Interval, errors: Errors, run_dirs: list[str]) -> dict:
    """The issue's acceptance checks on what was measured (RSS: growth after the first hour, if it got there)."""
    if not rows:  # stopped before its first report line (e.g. every run raised): nothing passed
        return {"checks": {"no_unhandled_exceptions": errors.count == 0, "ran": False},
                "rss_growth_after_first_hour": None, "ok": False}
    last = rows[-1]
    after_first = [r for r in rows if r["sim_h"] > 1.0 + 1e-9]
    base = next((r for r in rows if r["sim_h"] >= 1.0 - 1e-9), None)
    growth = (max(r["rss_mb"] for r in after_first) / base["rss_mb"] - 1.0) if base and after_first else None
    fds_after_first = [r["fds"] for r in rows[1:]] or [last["fds"]]
    checks = {
        "no_unhandled_exceptions": errors.count == 0,
        "no_points_lost": total.points_lost == 0 and total.events_lost == 0,
        "every_run_indexed": last["unindexed"] == 0 and last["library_entries"] >= len(run_dirs),
        "every_run_replayable": total.unreplayable == 0,
        "pads_off_after_every_abort": total.brake_violations == 0,
        "no_false_heartbeat_cuts": total.false_cuts == 0,
        "fds_flat": max(fds_after_first) - min(fds_after_first) <= 1,  # (one transient: the index file)
        "rss_growth_after_first_hour_ok": None if growth is None else growth <= RSS_GROWTH_MAX,
    }
    return {"checks": checks, "rss_growth_after_first_hour": None if growth is None else round(growth, 4),
            "ok": all(v is not False for v in checks.values())}


def soak(args) -> dict:
    root = Path(args.runs_dir) if args.runs_dir else Path(tempfile.mkdtemp(prefix="dyno-soak-"))
    root.mkdir(parents=True, exist_ok=True)
    os.environ["DYNO_RUNS_DIR"] = str(root)  # run_test's default run dirs and index_after_run's library
    errors, warns = Errors(), []
    log = sys.stderr if args.json else sys.stdout  # --json: stdout carries the one document
    errors.install()
    rng = random.Random(args.seed)
    end_s, every_s, drill_every_s = args.hours * 3600.0, args.report_min * 60.0, args.drill_every_min * 60.0
    from dyno.session.drills import parse_drill

    sim_s, next_report_s, next_drill_s = 0.0, every_s, drill_every_s
    iv, total, rows, run_dirs, bad_runs = Interval(), Interval(), [], [], []
    wall0 = time.monotonic()
    k = failed_in_a_row = 0
    print(f"soak: {args.hours:g} simulated h, fault rate {args.fault_rate}, a drill every {args.drill_every_min:g} "
          f"simulated min, runs in {root}; start RSS {rss_mb():.1f} MB fds {open_fds()}", file=log, flush=True)
    plans = args.plans.split(",") if args.plans else PLANS
    while sim_s < end_s:
        plan = plans[k % len(plans)]
        drill = None
        if sim_s >= next_drill_s:  # the drill due: on this run, at a random onset
            drill = parse_drill(f"{rng.choice(DRILLS)}@{rng.choice(ONSETS)}")
            next_drill_s += drill_every_s
        try:
            rec = one_run(plan, args.seed + k, drill, args.fault_rate, errors, warns)
        except KeyboardInterrupt:  # Ctrl+C between two runs (within one, the run's handler takes it)
            rec = {"stop": "SIGINT between runs"}
        k += 1
        if rec.get("stop"):  # SIGINT/SIGTERM meant for the soak: end it here, with its figures
            print(f"soak: stopped: {rec['stop']}", file=log, flush=True)
            end_s = sim_s + rec.get("sim_s", 0.0)
            if "state" not in rec:
                break
        failed_in_a_row = failed_in_a_row + 1 if rec["state"] == "exception" else 0
        sim_s += rec["sim_s"]
        if rec.get("run_dir"):
            run_dirs.append(rec["run_dir"])
        iv.add(rec)
        total.add(rec)
        if (rec["state"] == "exception" or rec.get("replayed") != rec.get("points") or not rec.get("indexed")
                or (rec.get("events_lost") and not stalls_host(rec["drill"]))
                or not (rec.get("pads_off") and rec.get("rig_safe") and rec.get("physics_safe"))):
            bad_runs.append(rec)
            print(f"  finding: {json.dumps(rec, default=str)}", file=log, flush=True)
        # one line per interval crossed (a long run can span two); the last one at the end, whatever it is
        while sim_s >= next_report_s or (sim_s >= end_s and iv.runs):
            at_s = next_report_s if sim_s >= next_report_s else sim_s
            rows.append(report_row(at_s / 3600.0, iv, total, time.monotonic() - wall0, root, run_dirs, errors))
            print_row(rows[-1], log)
            iv = Interval()
            next_report_s += every_s if at_s == next_report_s else 0.0
        if failed_in_a_row >= 5:  # (a run that raises adds no simulated time: never loop on it)
            print(f"soak: stopped: {failed_in_a_row} runs in a row raised", file=log, flush=True)
            break
    out = {"hours": args.hours, "sim_s": round(sim_s, 1), "wall_s": round(time.monotonic() - wall0, 1),
           "runs": total.runs, "points": total.points, "aborts": dict(sorted(total.aborts.items())),
           "drills": total.drills, "drills_fired": total.drills_fired, "rows": rows,
           "exceptions": errors.count, "exception_texts": errors.first, "index_warnings": warns[:5],
           "findings": bad_runs[:20], **verdict(rows, total, errors, run_dirs)}
    if not args.runs_dir:
        shutil.rmtree(root, ignore_errors=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=8.0, help="simulated hours (default 8)")
    ap.add_argument("--report-min", type=float, default=60.0, help="simulated minutes between report lines")
    ap.add_argument("--drill-every-min", type=float, default=10.0, help="simulated minutes between drills")
    ap.add_argument("--fault-rate", type=float, default=0.01, help="mixed transfer faults (default 0.01)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--plans", help=f"comma-separated plans, in turn (default: {','.join(PLANS)})")
    ap.add_argument("--runs-dir", help="keep the runs here (default: a temporary directory, deleted)")
    ap.add_argument("--quick", action="store_true",
                    help="CI smoke run: 6 simulated minutes of the short plans, a line every 3, a drill every 1.5")
    ap.add_argument("--json", action="store_true", help="the final document as JSON on stdout")
    args = ap.parse_args(argv)
    if args.quick:
        args.hours, args.report_min, args.drill_every_min = 6 / 60, 3.0, 1.5
        args.plans = args.plans or QUICK_PLANS
    if not (args.hours > 0 and args.report_min > 0 and args.drill_every_min > 0 and 0 <= args.fault_rate < 1):
        ap.error("--hours, --report-min, --drill-every-min must be > 0 and --fault-rate in [0, 1)")
    out = soak(args)
    if args.json:
        print(json.dumps(out, indent=1, default=str))
    else:
        v = out["checks"]
        print(f"soak: {out['runs']} runs, {out['points']} points, {out['sim_s'] / 3600:.2f} simulated h in "
              f"{out['wall_s']:.0f} s wall; aborts {out['aborts']}; RSS growth after the first hour "
              f"{out['rss_growth_after_first_hour']}; " + ", ".join(f"{k} {v[k]}" for k in v))
        for text in out["exception_texts"]:
            print("exception:", text, file=sys.stderr)
    return 0 if out["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
