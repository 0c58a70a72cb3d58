#!/usr/bin/env python3
"""Every drill on every shipped plan, at onsets in each phase: the safe state as the physics sees it.

For each (plan, drill, phase, mode) it runs ``dyno run --sim`` in-process (the same composition root the
command uses, signal handlers included) with the drill at ``@PHASE[+S]`` (``dyno.session.drills.PHASES``: armed =
idle, loaded = the pads first bite (contact search / stepping / holding), measure, after = after the test)
and prints one row: the cause, whether the drill's hazard arose, the safe-state latency in true time from
the physical onset against its bound, the brake position when the safe state came, the release time
(safe state commanded -> pads off the rotor, true time) against (position - free travel) / speed + 0.2 s,
``rig_safe`` as reported beside the physics' own verdict (pads off, actuator off, throttle idle, ignition
killed), the points kept and replayed, and whether ``dyno runs --json`` lists the run with its state.

Modes: ``fil`` (the Nano's real ELF in simavr, ``--firmware-elf``: the drills that concern the Nano or its link;
build it first: ``make -C firmware sim``), ``sim`` (the simulated driver), ``mock`` (``--mock-pins``: the real-rig output code on gpiozero's
MockFactory), ``sim+faults`` (``--fault-rate 0.01``), these three on the shipped rig file (K3 fitted), and the
wiring twin: ``twin`` (``--mock-pins`` with a rig file declaring the end switch and the E-stop monitor input, K3
not fitted: the driver's own release is judged) and ``twin+k3`` (the same with K3 fitted).  The wiring drills
(:mod:`dyno.session.drills_wiring`) run on the twin modes only; on every ``mock``/``twin`` row the driver's verdict must
agree with the physics (``driver_agrees``).

    python bench/bench_safe_state.py [--quick] [--plans a,b] [--drills x,y] [--phases p,q]
                                     [--modes sim,mock,sim+faults,twin,twin+k3] [--workers N] [--markdown] [--json]

``--quick`` (CI's smoke run): every plan once, one mid-test drill each, on ``sim``; plus one ``mock`` row and
two ``twin`` rows (and one ``fil`` row where the ELF is built).  The full matrix is 8 plans x 25 drills x 4 phases
x 5 modes + the ``fil`` column, less the wiring drills off the twin, plus the 3 kill-chain drills at ``@0`` only
(~3,500 runs, hours on 2 cores): run by hand, or a slice of it with the filters
(``--modes twin,twin+k3 --drills wiring``: the wiring drills alone); docs/safety.md has the figures.
"""

from __future__ import annotations

from dataclasses import replace

import argparse
import json
import math
import re
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

PLANS = ("speed-hold", "thesis-step", "torque-hold", "engine-hold", "sweep", "engagement", "coast-down",
         "drive-grid")
#: drill -> bound on latency_s from the physical onset (None: the run is expected to survive)
DRILLS = {
    "device-reset": None, "hall-dead:primary": 0.5, "hall-dead:secondary": 0.5, "hall-dead:both": 0.5,
    "thermometer-stuck": 5.0, "thermometer-lost": 5.0, "adc-error": 0.1, "adc-stuck": 2.0, "bus-lost": 0.35,
    "overtemp": 0.3, "overspeed": 0.1, "loop-stall:200": None, "loop-stall:800": 0.6, "controller-crash": 0.1,
    "disk-full": 0.1, "sigint": 0.1, "sigterm": 0.1, "sighup": 0.1,
    "pi-freeze": 0.3,  # freeze -> the kill chain opening (the Nano's heartbeat 0.2 s + 0.1 s)
    "loop-freeze": 0.3,  # the loop alone frozen: the same bound (the I/O thread stops the heartbeat within 0.05 s)
    # the wiring drills (twin modes only): a stuck or chattering end switch does not trip the run (the driver
    # finds it, names it, falls back to the full stroke time: judged on the physics at the end)
    "endswitch-stuck-closed": None, "endswitch-stuck-open": None, "endswitch-bounce": None,
    "estop-held:3": 0.1, "watchdog-error": 0.1, "sigint-in-command": 0.1,
    # the kill-chain drills (issue 49): a path broken from the start; the probe before GO ends the test (no bound:
    # judged on the abort's cause and path, no point, the brake never applied)
    "kill-lead-open": None, "kill-relay-welded": None, "run-enable-shorted": None,
}
WIRING = ("endswitch-stuck-closed", "endswitch-stuck-open", "endswitch-bounce", "estop-held:3", "watchdog-error",
          "sigint-in-command")
KILL = ("kill-lead-open", "kill-relay-welded", "run-enable-shorted")  # posed at @0 only: before the engine starts
PHASES = ("armed", "loaded+2", "measure+1", "after+0.5")
MODES = ("sim", "mock", "sim+faults", "twin", "twin+k3", "fil")
#: ``fil``: the Nano's real ELF in simavr as the rig's Nano (``--firmware-elf``), on the drills that concern the
#: Nano or its link (issue 55)
FIL_DRILLS = ("pi-freeze", "loop-freeze", "loop-stall:200", "loop-stall:800", "device-reset", "overspeed",
              "bus-lost", "hall-dead:primary", "hall-dead:secondary", "hall-dead:both", "adc-stuck")
FIL_ELF = Path(__file__).resolve().parent.parent / "firmware" / "build" / "dyno_nano.elf"
TWIN_MODES = ("twin", "twin+k3")
QUICK = {"speed-hold": "bus-lost@loaded+2", "thesis-step": "adc-stuck@loaded+2",
         "torque-hold": "controller-crash@loaded+2", "engine-hold": "loop-stall:800@loaded+2",
         "sweep": "hall-dead:both@loaded+1", "engagement": "sigterm@loaded+0.5",
         "coast-down": "disk-full@settle+1", "drive-grid": "adc-error@measure+1"}


def wired_rig_file(out_dir: Path, k3: bool) -> Path:
    """hardware/rig.toml with the end switch and the E-stop monitor input declared, K3 as asked."""
    text = (Path(__file__).resolve().parent.parent / "hardware" / "rig.toml").read_text()
    text = text.replace("# estop_input = 22 ", "estop_input = 22 ")
    text = text.replace("# brake_released_input = 27 ", "brake_released_input = 27 ")
    text, n = re.subn(r"^brake_hold_relay = (true|false)", f"brake_hold_relay = {'true' if k3 else 'false'}",
                      text, flags=re.M)
    assert n == 1, "hardware/rig.toml: no [actuator] brake_hold_relay line to set"
    path = out_dir.parent / f"{out_dir.name}.rig.toml"
    path.write_text(text)
    return path


def run_one(plan: str, drill_text: str, mode: str, out: str, seed: int = 3) -> dict:
    from dyno.resources import DEFAULT_ENGINE_MAP
    from dyno.session.root import RunSpec, run_test
    from dyno.cli.run_cmd import exit_code
    from dyno.control.plans import plan_named
    from dyno.session.drills import parse_drill
    from dyno.runlog.reader import load_run

    held: dict = {}
    rig = wired_rig_file(Path(out), k3=mode == "twin+k3") if mode in TWIN_MODES else None
    opts = RunSpec(sim=True, seed=seed, out_dir=Path(out), drills=[parse_drill(drill_text)],
                      handle_signals=True, plan=plan_named(plan), setup=lambda ctx: held.update(ctx=ctx),
                      mock_pins=mode in ("mock", *TWIN_MODES), fault_rate=0.01 if mode == "sim+faults" else 0.0,
                      rig_path=rig, firmware_elf=FIL_ELF if mode == "fil" else None)
    if plan == "drive-grid":
        opts = replace(opts, engine_map_path=DEFAULT_ENGINE_MAP.with_name("baja-10hp-representative-part-throttle.csv"))
    r = run_test(opts)
    m = held["ctx"].sim.model
    physics_safe = (m.actuator_mm <= m.brake.a0_mm and m.actuator_dir == 0 and m.throttle_frac == 0.0
                    and not m.magneto_fires)  # (no spark: a welded path or an open kill lead leave it firing)
    truth = held["ctx"].sim.truth
    a = r["aborts"][0] if r["aborts"] else {}
    d = (r.get("drills") or [{}])[0]
    out_s = r["outputs"]
    try:
        replayed = len(load_run(r["run_dir"]).docs("point"))
    except Exception as exc:  # noqa: BLE001 - the table reports it
        replayed = f"unreadable: {exc}"
    return {"plan": plan, "drill": drill_text, "mode": mode, "state": r["state"], "cause": a.get("cause", "-"),
            "fired": bool(d), "hazard_arose": d.get("hazard_arose"), "hazard_note": d.get("hazard_note", ""),
            "state_at_onset": d.get("state_at_onset"),
            "latency_s": a.get("latency_s"), "detection_s": a.get("detection_s"),
            "brake_mm_at_safe": out_s.get("brake_position_at_safe_mm"), "release_s": out_s.get("release_s"),
            "release_bound_s": out_s.get("release_bound_s"), "rig_safe": r["rig_safe"],
            "driver_agrees": out_s.get("driver_agrees"), "driver_disagreement": out_s.get("driver_disagreement"),
            "rig_faults": len(r.get("rig_faults") or []),
            "physics_safe": bool(physics_safe), "points": len(r["points"]), "replayed": replayed,
            "exit": exit_code(r), "run_dir": r["run_dir"], "path": a.get("path"),
            "pads_ever_on": any(x > m.brake.a0_mm for x in truth.act)}


def judge(row: dict) -> list[str]:
    """What is wrong with a row ([] = within every bound)."""
    bad = []
    name = row["drill"].partition("@")[0]
    bound = DRILLS.get(name)
    if name in KILL:  # the probe must end the test before any load, naming the broken path
        from dyno.session.drills_kill import KILL_DRILL_PATH

        if (row["state"], row["cause"], row.get("path")) != ("aborted", "kill_path_failed", KILL_DRILL_PATH[name]):
            bad.append(f"not ended by the kill-path probe: {row['state']} {row['cause']} {row.get('path')}")
        if row["points"] or row.get("pads_ever_on") or row.get("exit") != 3:
            bad.append("a point, a load or an exit code other than 3")
    if not row["physics_safe"] and name != "kill-lead-open":  # (that engine cannot be stopped: rig_safe says so)
        bad.append("physics not safe")
    if row["rig_safe"] != row["physics_safe"]:
        bad.append("rig_safe disagrees with the physics")
    if row["mode"] in ("mock", *TWIN_MODES) and row.get("driver_agrees") is not True:
        bad.append(f"driver disagrees: {row.get('driver_disagreement')}")
    if row["release_s"] is None or row["release_bound_s"] is None or row["release_s"] > row["release_bound_s"]:
        bad.append("release out of bound")
    if row["replayed"] != row["points"]:
        bad.append("points not replayed")
    if row.get("listed") is False:
        bad.append("not in the run library")
    aborted_by_it = row["state"] == "aborted" and row["fired"] and row["hazard_arose"]
    if bound is not None and aborted_by_it and row["state_at_onset"] not in ("done", "aborted"):
        lat = row["latency_s"]
        if lat is None or lat > bound:
            bad.append(f"latency {lat} > {bound}")
    return bad


def matrix(args) -> list[tuple[str, str, str]]:
    if args.quick:
        return [(p, d, "sim") for p, d in QUICK.items()] + [("speed-hold", "bus-lost@loaded+2", "mock"),
                                                             ("speed-hold", "endswitch-stuck-closed@loaded+2", "twin"),
                                                             ("thesis-step", "estop-held:3@loaded+2", "twin+k3")] + (
            [("thesis-step", "pi-freeze@loaded+2", "fil")] if FIL_ELF.is_file() else [])
    plans = args.plans.split(",") if args.plans else PLANS
    drills = WIRING if args.drills == "wiring" else (args.drills.split(",") if args.drills else list(DRILLS))
    phases = args.phases.split(",") if args.phases else PHASES
    modes = args.modes.split(",") if args.modes else MODES
    return [(p, f"{d}@{'0' if d in KILL else ph}", m) for m in modes for p in plans for d in drills
            for ph in (phases[:1] if d in KILL else phases)
            if (m in TWIN_MODES or d not in WIRING) and (m != "fil" or d in FIL_DRILLS)]


def _listed(runs_root: Path, rows: list[dict]) -> None:
    """Mark each row with whether the run library lists its run with the same final state."""
    from dyno.library import index as lib

    conn = lib.open_library(runs_root, warn=lambda line: None)
    lib.reindex(conn, runs_root)
    runs = {Path(r["path"]).name: (r.get("state"), r.get("n_points")) for r in lib.dump(conn).get("runs", [])}
    for row in rows:
        state, n = runs.get(Path(row["run_dir"]).name, (None, None))
        row["library_state"] = state
        # a full disk takes the run's last records with it: the library shows what reached the disk
        same = state == row["state"] or (row["drill"].startswith("disk-full") and state == "incomplete")
        row["listed"] = same and n == row["points"]


def fmt(v, spec="{:.3f}") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return spec.format(v) if isinstance(v, float) else str(v)


def markdown(rows: list[dict]) -> str:
    head = ("| plan | drill@phase | mode | state | cause | hazard | latency s | brake mm | release s | bound s "
            "| rig_safe | physics | driver agrees | rig faults | pts/replayed | ok |\n|" + "---|" * 16)
    lines = [head]
    for r in rows:
        lines.append(f"| {r['plan']} | {r['drill']} | {r['mode']} | {r['state']} | {r['cause']} | "
                     f"{fmt(r['hazard_arose'])} | {fmt(r['latency_s'])} | {fmt(r['brake_mm_at_safe'], '{:.2f}')} | "
                     f"{fmt(r['release_s'])} | {fmt(r['release_bound_s'])} | {r['rig_safe']} | "
                     f"{r['physics_safe']} | {fmt(r.get('driver_agrees'))} | {r.get('rig_faults', 0)} | "
                     f"{r['points']}/{r['replayed']} | "
                     f"{'ok' if not r['bad'] else '; '.join(r['bad'])} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="every plan once (CI smoke)")
    ap.add_argument("--plans", default=None)
    ap.add_argument("--drills", default=None, help="comma-separated, or \"wiring\": the wiring drills")
    ap.add_argument("--phases", default=None, help=f"comma-separated, default {','.join(PHASES)}")
    ap.add_argument("--modes", default=None, help=f"comma-separated, default {','.join(MODES)}")
    ap.add_argument("--workers", type=int, default=1, help="processes (signal drills need their own process)")
    ap.add_argument("--markdown", action="store_true", help="print the table as Markdown (docs/safety.md)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    cases = matrix(args)
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        outs = [str(Path(tmp) / f"{i:04d}-{p}-{d}-{m}".replace(":", "_").replace("@", "_").replace("+", "p"))
                for i, (p, d, m) in enumerate(cases)]
        # one run per process: a signal drill signals the process it runs in, and a fresh process keeps
        # each run's memory and handlers its own
        with ProcessPoolExecutor(max_workers=max(1, args.workers), max_tasks_per_child=1) as ex:
            futs = [ex.submit(run_one, p, d, m, o) for (p, d, m), o in zip(cases, outs)]
            for (p, d, m), fut in zip(cases, futs):
                try:
                    row = fut.result()
                except Exception as exc:  # noqa: BLE001 - a crashed run is a row, not the end of the bench
                    row = {"plan": p, "drill": d, "mode": m, "state": "crashed", "cause": repr(exc)[:80],
                           "fired": False, "hazard_arose": None, "latency_s": None, "brake_mm_at_safe": None,
                           "release_s": None, "release_bound_s": None, "rig_safe": None, "physics_safe": False,
                           "points": 0, "replayed": 0, "run_dir": "", "state_at_onset": None,
                           "driver_agrees": None}
                rows.append(row)
        _listed(Path(tmp), rows)
    for row in rows:
        row["bad"] = judge(row)
        if not (args.json or args.markdown):
            print(f"  {row['plan']:<12} {row['drill']:<30} {row['mode']:<10} {row['state']:<8} "
                  f"{row['cause']:<17} lat {fmt(row['latency_s']):>7} rel {fmt(row['release_s']):>6}"
                  f"/{fmt(row['release_bound_s']):>6} safe {row['rig_safe']}/{row['physics_safe']} "
                  f"{'ok' if not row['bad'] else 'BAD: ' + '; '.join(row['bad'])}", flush=True)
    n_bad = sum(1 for r in rows if r["bad"])
    if args.json:
        print(json.dumps(rows, indent=1))
    elif args.markdown:
        print(markdown(rows))
    rel = [r["release_s"] / r["release_bound_s"] for r in rows
           if r.get("release_s") is not None and r.get("release_bound_s")]
    driven = [r for r in rows if r["mode"] in ("mock", *TWIN_MODES)]
    print(f"{len(rows)} runs, {n_bad} out of bound; release/bound max {max(rel) if rel else math.nan:.3f}; "
          f"rig_safe agrees with the physics in {sum(r['rig_safe'] == r['physics_safe'] for r in rows)}"
          f"/{len(rows)}; driver_agrees in {sum(r.get('driver_agrees') is True for r in driven)}/{len(driven)} "
          f"rows through the Pi's code", file=sys.stderr)
    return 1 if n_bad else 0


if __name__ == "__main__":
    sys.exit(main())
