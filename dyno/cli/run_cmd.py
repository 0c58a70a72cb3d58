"""dyno run: a complete steady-state test."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def add_arguments(p) -> None:
    p.add_argument("--sim", action="store_true", help="run on the simulated rig (no hardware)")
    p.add_argument("--headless", action="store_true", help="no UI; GO is given automatically")
    from dyno.cli import number_in

    p.add_argument("--speed", type=number_in(0.0, 1000.0, lo_open=True), default=None,
                   help="simulation pace as a multiple of real time (default: as fast as possible)")
    p.add_argument("--seed", type=number_in(0, 2**32 - 1, integer=True), default=0, help="simulation seed")
    p.add_argument("--fault-rate", type=number_in(0.0, 0.5), default=0.0,
                   help="fraction of bus transfers corrupted, 0..0.5 (bit errors, NACKs, truncation)")
    p.add_argument("--mock-pins", action="store_true",
                   help="with --sim: drive the simulated rig through the real-rig output code (gpiozero "
                        "devices on MockFactory); outputs then reports the pins' final states")
    p.add_argument("--firmware-elf", type=Path, default=None, metavar="PATH",
                   help="with --sim: the Nano's real firmware ELF runs in simavr as the rig's Nano (firmware in the "
                        "loop: the physics drives its pins, the host polls it over the rig file's I2C link, its "
                        "run-enable feeds the kill chain); needs `make -C firmware sim`")
    p.add_argument("--out", type=Path, default=None, help="run directory (default: runs/<timestamp>)")
    p.add_argument("--protocol", choices=("v2", "v1", "v0"), default=None,
                   help="the firmware link's protocol (default: rig.toml's protocol; v0: the thesis rig's legacy "
                        "frame, docs/protocol.md)")
    p.add_argument("--calibration", type=Path, default=None, help="torque calibration history CSV")
    p.add_argument("--engine-map", type=Path, default=None, help="engine map CSV")
    p.add_argument("--tune", type=Path, default=None,
                   help="the CVT tune on the rig (TOML), stored with the run; with --sim the simulated CVT uses it")
    p.add_argument("--driven-loss", type=Path, default=None, metavar="FILE",
                   help="a coast-down's driven_loss.json: every point also gets its efficiency with the driven-side "
                        "loss the gauge does not see added back, uncertainty propagated (default: rig.toml "
                        "[driven] loss_file)")
    p.add_argument("--sim-driven-loss", default=None, metavar="A,B,C",
                   help="with --sim: the simulated rig's driven-side parasitic loss a + b w + c w^2 (N m, w in "
                        "rad/s of the secondary; off by default), the truth a coast-down recovers")
    p.add_argument("--sim-zero-drift", type=float, default=None, metavar="NM_PER_MIN",
                   help="with --sim: the torque channel's zero drifts by this many N m (secondary) per minute")
    add_air_arguments(p)
    p.add_argument("--settle", choices=("detect", "fixed"), default=None,
                   help="step plans' settling: detected from the data, or the thesis's fixed 4 s (default: the plan's)")
    p.add_argument("--plan", default="speed-hold", metavar="NAME|FILE",
                   help="a shipped plan (speed-hold: closed-loop secondary-speed setpoints, each point to a 95 %% "
                        "CI of +-1 pp, the default; thesis-step: the thesis's open-loop brake steps; sweep; "
                        "torque-hold; engine-hold; engagement: throttle ramps -> engagement, lock-up, shift-out "
                        "(vs load), full-shift ratio; coast-down: the driven side's parasitic loss; drive-grid: throttle x "
                        "secondary-speed grid, with a part-throttle --engine-map; ...) or a plan "
                        "file (a path ending in .toml; docs/control.md)")
    p.add_argument("--json", action="store_true", help="print one JSON document (on every way out)")
    from dyno.session.drill_help import drill_help

    p.add_argument("--drill", action="append", default=[], metavar="NAME[:ARG]@WHEN", help=drill_help())
    from dyno.rig.locate import add_rig_argument
    from dyno.web.attach import add_web_arguments

    add_web_arguments(p)  # --web [ADDR:PORT], --web-stop (docs/web.md)
    add_rig_argument(p)


def add_air_arguments(p) -> None:
    """--ambient and the simulated world's flags (dyno run, dyno ui)."""
    p.add_argument("--ambient", default=None, metavar="TEMP_C,PRESSURE_KPA[,RH_PCT]",
                   help="the day's intake air (station pressure, as a barometer reads it): the engine map is taken "
                        "to it by SAE J1349 (default: rig.toml [ambient]'s sensor or day; neither: uncorrected)")
    p.add_argument("--sim-ambient", default=None, metavar="TEMP_C,PRESSURE_KPA,RH_PCT",
                   help="with --sim: the simulated day (default: drawn per seed). The host is not told it")
    p.add_argument("--sim-engine-dev", type=float, default=None, metavar="REL_SD",
                   help="with --sim: relative sd of the simulated engine's smooth deviation from its map "
                        "(default 0.044, the simulator's own: dyno/sim/rig_params.py; 0: exactly the map's shape)")
    p.add_argument("--sim-engine-ageing", type=float, default=None, metavar="FRAC",
                   help="with --sim: the simulated engine makes this fraction less than its map (worn)")
    p.add_argument("--sim-cal-drift", type=float, default=None, metavar="REL_SD",
                   help="with --sim: relative sd of the torque sensor's gain drift from its latest calibration "
                        "(default 0.015, re-seating and re-calibration scatter; 0: none; the thermal drift with "
                        "the day's temperature, 0.025 %%/K from 20 C, stays)")
    p.add_argument("--sim-world-seed", type=int, default=None, metavar="N",
                   help="with --sim: draw the engine, sensor and day from this seed instead of --seed (the same "
                        "rig measured again: compare runs that share it)")
    p.add_argument("--sim-tune-deviation", type=float, default=None, metavar="REL",
                   help="with --sim: each CVT part's true value (spring preloads and rates, flyweight mass and "
                        "centre of mass, helix angle and radius) differs from its label by up to REL, normal with "
                        "each field's own spread, drawn per part and world seed: the same part keeps its "
                        "deviation on the same rig across runs (default 0)")
    p.add_argument("--sim-belt-thrust", type=float, default=None, metavar="F",
                   help="with --sim: the simulated belt requires the secondary thrust of the capstan tier at "
                        "belt-sheave friction F (0.4 is the thesis's); default: the full belt model's thrust "
                        "ratio, from its table at the operating point (docs/belt-model.md)")
    p.add_argument("--sim-brake-start", type=float, default=None, metavar="MM",
                   help="with --sim: the simulated brake starts applied at MM of the actuator's travel (0..40; "
                        "default 0, released); the host is not told (docs/safety.md, start-up)")
    p.add_argument("--sim-ideal", action="store_true",
                   help="with --sim: perfect knowledge (the engine exactly its map, the sensor exactly its "
                        "calibration, the J1349 reference day): for checks of statistics alone")


def air_options(args, sim_kw: dict, prog: str = "dyno run"):
    """(ambient, error line): --ambient parsed, the sim-world flags put into ``sim_kw``."""
    from dyno.analysis.air import parse_ambient

    ambient = None
    try:
        if args.ambient is not None:
            ambient = parse_ambient(args.ambient, "--ambient")
        if args.sim_ambient is not None:
            day = parse_ambient(args.sim_ambient, "--sim-ambient")
            sim_kw["ambient_day"] = (day.temp_c, day.pressure_kpa, 40.0 if day.rh_pct is None else day.rh_pct)
    except ValueError as exc:
        return None, f"{prog}: {exc}"
    for flag, key, hi in (("sim_engine_dev", "engine_map_dev_rel_sd", 0.5),
                          ("sim_engine_ageing", "engine_ageing_loss_frac", 0.9),
                          ("sim_cal_drift", "adc_gain_drift_rel_sd", 0.5)):
        v = getattr(args, flag)
        if v is not None:
            if not 0.0 <= v <= hi:
                return None, f"{prog}: --{flag.replace('_', '-')}: expected a number 0..{hi:g}, got {v:g}"
            sim_kw[key] = float(v)
    if args.sim_ideal:
        sim_kw["ideal"] = True
    brake_mm = getattr(args, "sim_brake_start", None)
    if brake_mm is not None:
        from dyno.sim.rig_params import RigParams

        travel_mm = RigParams.actuator_travel_mm
        if not (0.0 <= brake_mm <= travel_mm):  # (NaN fails too)
            return None, f"{prog}: --sim-brake-start: expected millimetres of travel 0..{travel_mm:g}, got {brake_mm:g}"
        sim_kw["brake_start_mm"] = float(brake_mm)
    dev = getattr(args, "sim_tune_deviation", None)
    if dev is not None:
        if not (0.0 <= dev <= 0.5):  # (NaN fails too)
            return None, f"{prog}: --sim-tune-deviation: expected a number 0..0.5, got {dev:g}"
        sim_kw["tune_deviation_rel"] = float(dev)
    thrust = getattr(args, "sim_belt_thrust", None)
    if thrust is not None:
        if not (0.05 <= thrust <= 1.0):  # (NaN fails too)
            return None, f"{prog}: --sim-belt-thrust: expected a friction coefficient 0.05..1, got {thrust:g}"
        sim_kw["cvt_belt_friction_coefficient"] = float(thrust)
    if args.sim_world_seed is not None:
        if not 0 <= args.sim_world_seed < 2**32:
            return None, f"{prog}: --sim-world-seed: expected 0..{2**32 - 1}, got {args.sim_world_seed}"
        sim_kw["world_seed"] = int(args.sim_world_seed)
    return ambient, None


def plan_named(name: str, **overrides):
    """A shipped plan by name, a code plan, or a plan file (dyno.control.plans); bad ones raise ConfigError."""
    from dyno.control.plans import plan_named as _plan_named

    return _plan_named(name, **overrides)


#: exit codes (docs/safety.md): 0 done, 2 bad input, 3 aborted to the safe state, 128+N signal N
EXIT_DONE, EXIT_BAD_INPUT, EXIT_ABORTED = 0, 2, 3


def exit_code(result: dict) -> int:
    if result.get("signal"):
        return 128 + int(result["signal"])
    return EXIT_DONE if result["state"] == "done" else EXIT_ABORTED


def run_spec(args):
    """(spec, driven loss or None, error line or None): ``dyno run``'s arguments as a :class:`dyno.session.root.RunSpec`."""
    from dyno.session.root import RunSpec
    from dyno.session.drills import parse_drill

    drills = [parse_drill(d) for d in args.drill]
    kw = dict(sim=True, seed=args.seed, speed=args.speed, fault_rate=args.fault_rate, out_dir=args.out,
              protocol=args.protocol, rig_path=getattr(args, "rig", None), plan=_plan(args), drills=drills,
              handle_signals=True, mock_pins=args.mock_pins, firmware_elf=args.firmware_elf,
              on_belt_table_build=_announce_belt_table)
    driven_loss = _driven_loss(args)  # a bad file: one line, exit 2, before anything is written
    if args.calibration:
        kw["calibration_path"] = args.calibration
    if args.engine_map:
        kw["engine_map_path"] = args.engine_map
    sim_kw = {}
    if args.tune:
        kw["tune_path"] = args.tune
        sim_kw["cvt_tune_path"] = str(args.tune)
    if args.sim_driven_loss is not None:
        try:
            coeffs = tuple(float(v) for v in args.sim_driven_loss.split(","))
            if len(coeffs) != 3 or not all(c >= 0 for c in coeffs):
                raise ValueError
        except ValueError:
            return None, None, (f"dyno run: --sim-driven-loss: expected three numbers >= 0 as A,B,C, got "
                                f"{args.sim_driven_loss!r}")
        sim_kw["driven_loss_nm"] = coeffs
    if args.sim_zero_drift is not None:
        sim_kw["adc_zero_drift_nm_per_min"] = float(args.sim_zero_drift)
    kw["ambient"], bad = air_options(args, sim_kw)
    if bad:
        return None, None, bad
    if sim_kw:
        from dyno.sim.rig_params import RigParams

        kw["sim_params"] = RigParams(**sim_kw)
    return RunSpec(**kw), driven_loss, None


def _announce_belt_table(name) -> None:
    print(f"dyno run: the simulated CVT solves its belt-model table for tune {name or '(none)'} (once per tune and "
          "model version, cached; about 1-2 min)", file=sys.stderr, flush=True)


def run(args) -> int:
    """parse (argparse) -> spec (:func:`run_spec`) -> call (:func:`dyno.session.root.run_test`) -> print."""
    if not args.sim:
        print("dyno run: only --sim is available headless here; on the rig use `dyno ui`", file=sys.stderr)
        return 2
    spec, driven_loss, bad = run_spec(args)
    if bad:
        print(bad, file=sys.stderr)
        return 2
    from dataclasses import replace

    from dyno.rig.locate import find_rig
    from dyno.session.root import run_test

    rig_file = find_rig(spec.rig_path)  # (said once the run has read it: a bad file is one line, this none)
    from dyno.cli import progress as tty

    bar = None
    if tty.wanted(args.json):  # a person at a terminal: one live status line on stderr
        bar = tty.TtyProgress()
        spec = replace(spec, setup=bar.attach)
    web, spec = _web(args, spec)
    if web is False:
        return 2
    import time

    wall0_s = time.monotonic()
    result = None
    try:
        result = run_test(spec)
    finally:
        if bar is not None:
            bar.finish()
        if web is not None:
            web.end(result)
    from dyno.session.after import add_driven_loss

    add_driven_loss(result, driven_loss, getattr(args, "rig", None))
    result["rig_file"] = rig_file.to_dict()  # {"path", "found_by"}
    _index(result)  # first: what follows writes to a terminal that may have gone (SIGHUP)
    link = result.get("link") or {}
    try:
        print(f"dyno run: {rig_file.line()}", file=sys.stderr, flush=True)
        if "link_busy" in link.get("warnings", ()):  # (dyno.transports.budget: measured above the planning limit)
            print(f"dyno run: warning: link_busy: the busiest second measured "
                  f"{100 * link['measured_busy_frac']:.0f} % of the link (planned "
                  f"{100 * link['planned_busy_frac']:.0f} %, limit 60 %)", file=sys.stderr)
        _speed_note(args.speed, result, time.monotonic() - wall0_s)
    except OSError:  # a vanished terminal: the run is on disk and indexed
        pass
    try:
        if args.json:
            print(json.dumps(result, indent=1, default=str, allow_nan=False))
        else:
            print_result_table(result)
        sys.stdout.flush()
    except (BrokenPipeError, OSError):  # a closed pipe or a vanished terminal (SIGHUP): the run is on disk
        pass
    if result.get("log_error"):
        print(f"dyno run: {result['run_dir']}: {result['log_error']}: safe state reached; "
              "what was recorded before is readable with `dyno replay`", file=sys.stderr)
    if result.get("signal") != 1:  # SIGHUP: the terminal went, end now (`dyno report RUN` writes it later)
        _write_report(result, announce=not args.json)
    return exit_code(result)


def _web(args, spec):
    """(web, spec) --web: the server started (its URL on stderr) and hooked to the run when it is built; None
    without --web, False after one line saying why not.  The page is for people: the run goes at real time
    (--speed 1) unless --speed says otherwise."""
    if args.web is None and not args.web_stop:
        return None, spec
    from dataclasses import replace

    from dyno.web.attach import WebView

    web = WebView.start("dyno run", args)
    if web is None:
        return False, spec
    speed = 1.0 if spec.speed is None else spec.speed
    before = spec.setup

    def setup(ctx) -> None:
        import asyncio

        from dyno.web.feed import RunSource

        if before is not None:
            before(ctx)
        loop = asyncio.get_running_loop()
        web.attach(RunSource(ctx, loop, speed), loop)

    return web, replace(spec, speed=speed, setup=setup)


def _driven_loss(args):
    """The --driven-loss file, else rig.toml [driven] loss_file, loaded and checked (None: none asked)."""
    from dyno.analysis.coastdown import load_driven_loss

    path = args.driven_loss
    if path is None:
        from dyno.rig.config import load_rig

        path = load_rig(getattr(args, "rig", None)).driven.loss_file
    return None if path is None else load_driven_loss(path)


def _plan(args):
    """The plan ``--plan`` names; ``--settle`` overrides its settle mode only when given."""
    over = {"settle_mode": args.settle} if args.settle is not None else {}
    return plan_named(args.plan, **over)


def _write_report(result: dict, *, announce: bool) -> None:
    """report.html into the run directory, last of all: a failure is one stderr line, never another exit code."""
    from dyno.session.after import write_run_report

    path = write_run_report(result.get("run_dir"), _warn)
    if path is not None and announce:
        try:
            print(f"report: {path}")
            sys.stdout.flush()
        except OSError:  # a closed pipe: the report is on disk all the same
            pass


def _warn(line: str) -> None:
    try:
        print(f"dyno run: {line}", file=sys.stderr)
    except OSError:
        pass


def _speed_note(asked: float | None, result: dict, wall_s: float) -> None:
    """--speed N is a pace, not a promise: if this machine could not keep it, say so (one line)."""
    sim_s = result.get("sim_time_s")
    if asked is None or not sim_s or wall_s <= 0:
        return
    got = sim_s / wall_s
    if got < 0.8 * asked:
        print(f"dyno run: --speed {asked:g} not reached: the simulation ran at {got:.1f}x real time on this "
              "machine (CPU-bound); the results do not depend on it", file=sys.stderr)


def _index(result: dict) -> None:
    """Add the run to the run library (docs/library.md); a failure is one stderr line, never the exit code."""
    from dyno.session.after import index_run

    if result.get("run_dir"):
        index_run(result["run_dir"], lambda line: print(f"dyno run: {line}", file=sys.stderr))


def air_line(amb: dict) -> str:
    """One line on the run's air: the J1349 factor the map was taken to the day by, or "uncorrected"."""
    if amb.get("j1349_factor") is None:
        return ("air: uncorrected (no BME280, no --ambient, no rig.toml [ambient] day): the map is the standard "
                "day's, and each point's efficiency_interval95 covers a plausible day (asymmetric: the truth is up to "
                "~30 % above the figure)")
    rh = amb.get("rh_pct")
    return (f"air: {amb['temp_c']:.1f} C, {amb['pressure_kpa']:.2f} kPa" + (f", {rh:.0f} %RH" if rh is not None else "")
            + f" ({amb.get('source')}): SAE J1349 factor {amb['j1349_factor']:.4f} applied to the engine map")


def _print_figures(result: dict) -> None:
    """A characterisation's figures (the engagement plan's have no points table), the tune's prediction of
    them, and what ``dyno tune advise`` predicted if the tune is one it advised."""
    def fig(key, unit="rpm", fmt="{:.0f}"):
        v, ci = result.get(key), result.get(f"{key}_ci95")
        if not isinstance(v, (int, float)) or v != v:
            return None
        return fmt.format(v) + ("" if not isinstance(ci, (int, float)) or ci != ci else " ± " + fmt.format(ci)) \
            + (f" {unit}" if unit else "")

    rows = [(name, fig(key, unit, fmt)) for name, key, unit, fmt in (
        ("engagement", "engagement_rpm", "rpm", "{:.0f}"), ("lock-up", "lockup_rpm", "rpm", "{:.0f}"),
        ("shift-out", "shift_out_rpm", "rpm", "{:.0f}"), ("full-shift ratio", "full_shift_ratio", "", "{:.3f}"))]
    rows = [(n, v) for n, v in rows if v is not None]
    if not rows:
        return
    load = result.get("shift_out_torque_nm")
    at = f" (shift-out at {load:.1f} N·m)" if isinstance(load, (int, float)) and load == load else ""
    print("figures (± 95 %): " + ", ".join(f"{n} {v}" for n, v in rows) + at)
    pred = result.get("predicted") or {}
    pp = [f"{n} {pred[k]:.0f}" for n, k in (("engagement", "engagement_rpm"), ("shift-out", "shift_out_rpm"))
          if isinstance(pred.get(k), (int, float))]
    if pp:
        print(f"tune {result.get('tune') or ''} predicts: " + ", ".join(pp) + " rpm (its labels, uncalibrated)")
    if result.get("run_dir"):
        from dyno.library.advice import advised_for_run, format_line
        from dyno.library.index import runs_dir

        adv = advised_for_run(runs_dir(), result["run_dir"])
        if adv is not None:
            print(format_line(adv))


def print_result_table(result: dict) -> None:
    print(f"run: {result['run_dir']}  state: {result['state']} ({result['reason']})")
    if result["points"]:
        _print_points(result["points"], result.get("u95_terms"))
    for why in result.get("skipped") or []:  # a setpoint the plan asked for that gave no point, and why
        print(f"skipped: {why}")
    _print_figures(result)
    print(air_line(result.get("ambient") or {}))
    fr = result["frames"]
    print(f"frames: read {fr['read']}, accepted {fr['accepted']}, rejected {fr['rejected']}; "
          f"events lost {result['events_lost']}")
    link = result.get("link") or {}
    if link.get("transport"):
        print(f"link: {link['transport']} at {link['clock_hz']} {'Bd' if link['transport'] == 'serial' else 'Hz'}, "
              f"{link['poll_hz']:g} polls/s, worst second {100 * (link['bus_busy_frac'] or 0):.0f} % busy "
              f"({link['busy_basis']}), frames lost {link['frames_lost']}")
    for f in result.get("rig_faults") or []:
        print(f"RIG FAULT: {f['channel']}: {f['detail']}")
    for a in result["aborts"]:
        print(f"ABORT: {a['cause']}: {a['detail']}")
    if result["aborts"]:
        print(f"rig safe: {'yes' if result.get('rig_safe') else 'NO'}  outputs: "
              + ", ".join(f"{k}={round(v, 3) if isinstance(v, float) else v}"
                          for k, v in result.get("outputs", {}).items()
                          if k != "safe" and not isinstance(v, (list, dict))))


def _print_points(points: list, terms=None) -> None:
    """The points table: each efficiency with its 95 % CI (the point's own statistics, ``efficiency_ci95``), the
    interval the truth lies in at 95 % (``efficiency_interval95``: statistics and every systematic term,
    asymmetric where a term is, at most 100 %) and its half-width ``efficiency_u95`` (±U95: the same statement,
    not a second one), both ± half-widths in pp; the speed
    ratio; where P_in comes from (``map``: the engine map at the point's speed and throttle, ``meas``: the input
    torque channel).  Its footer names the term that dominates U95, what ``dyno compare`` cancels, and what
    would narrow the intervals when that is obvious (an engine map not measured on this engine)."""
    from dyno.analysis.u95_terms import COMPARE_NOTE, advice, largest_term_text

    print(f"{'#':>3} {'rpm_p':>6} {'rpm_s':>6} {'ratio':>5} {'T_s N·m':>7} {'P_out W':>7} {'P_in W':>6} {'from':<4} "
          f"{'eff %':>5} {'±CI95':>5} {'±U95':>5} {'interval95 %':>12}")
    for p in points:
        def f(k, scale=1.0, fmt="{:.0f}"):
            v = p.get(k)
            return "-" if v is None else fmt.format(v * scale)
        iv = p.get("efficiency_interval95")
        interval = "-" if not iv or None in iv else f"{100 * iv[0]:.1f}..{100 * iv[1]:.1f}"
        source = "meas" if p.get("efficiency_source") == "input_torque" else "map"
        print(f"{p.get('index', ''):>3} {f('rpm_primary'):>6} {f('rpm_secondary'):>6} {f('ratio', fmt='{:.2f}'):>5} "
              f"{f('torque_secondary_nm', fmt='{:.2f}'):>7} {f('power_out_w'):>7} {f('power_in_w'):>6} {source:<4} "
              f"{f('efficiency', 100, '{:.1f}'):>5} {f('efficiency_ci95', 100, '{:.1f}'):>5} "
              f"{f('efficiency_u95', 100, '{:.1f}'):>5} {interval:>12}")
    print("from: where P_in comes from (map: the engine map at the point's speed and throttle; meas: the input "
          "torque channel); ±U95: half the width of interval95, the point's one 95 % statement")
    largest = largest_term_text(points)
    if largest:
        print(f"{largest}; {COMPARE_NOTE}")
    if advice(terms, points):
        print(f"to narrow: {advice(terms, points)}")
