"""dyno ui: the live run screen (simulated rig with --sim)."""

from __future__ import annotations

from pathlib import Path

from dyno.cli import number_in


def add_arguments(p) -> None:
    p.add_argument("--sim", action="store_true", help="the simulated rig (no hardware)")
    p.add_argument("--speed", type=number_in(0.0, 1000.0, lo_open=True), default=1.0,
                   help="simulation pace as a multiple of real time (default 1: real time)")
    p.add_argument("--seed", type=number_in(0, 2**32 - 1, integer=True), default=0, help="simulation seed")
    p.add_argument("--out", type=Path, default=None, help="run directory (default: runs/<timestamp>)")
    p.add_argument("--calibration", type=Path, default=None, help="torque calibration history CSV")
    p.add_argument("--engine-map", type=Path, default=None, help="engine map CSV")
    p.add_argument("--plan", default="speed-hold", metavar="NAME|FILE",
                   help="the test plan: a shipped name (speed-hold, the default; thesis-step; sweep; torque-hold; "
                        "engine-hold; ...) or a plan file (a path ending in .toml; docs/control.md)")
    from dyno.session.drill_help import drill_help
    from dyno.session.drills import DRILLS

    p.add_argument("--drill", action="append", default=[], metavar="NAME[:ARG]@WHEN",
                   help=drill_help(n for n in DRILLS if n != "pi-freeze"))  # (pi-freeze: dyno run only)
    p.add_argument("--mock-pins", action="store_true",
                   help="--sim: drive the simulated physics through the real-rig output code (gpiozero MockFactory)")
    p.add_argument("--firmware-elf", type=Path, default=None, metavar="PATH",
                   help="--sim: the Nano's real firmware ELF in simavr as the rig's Nano, in lockstep with the physics "
                        "(--speed paces both)")
    from dyno.cli.run_cmd import add_air_arguments
    from dyno.rig.locate import add_rig_argument

    from dyno.web.attach import add_web_arguments

    add_air_arguments(p)
    add_web_arguments(p)  # --web [ADDR:PORT], --web-stop (docs/web.md)
    add_rig_argument(p)


def run(args) -> int:
    from dyno.ui.live_app import LiveApp
    from dyno.ui.session import LiveOptions

    if not args.speed > 0:
        raise SystemExit("dyno ui: --speed must be > 0")
    from dyno.session.drills import parse_drill
    from dyno.errors import ConfigError

    drills = [parse_drill(d) for d in args.drill]
    frozen = next((d.name for d in drills if d.name in ("pi-freeze", "loop-freeze")), None)
    if frozen:  # (before the screen is taken over: one line, exit 2)
        raise ConfigError("command line", "--drill", f"{frozen} freezes the host on the simulated clock (its "
                          "watchdog thread with it): only in simulated time (dyno run --sim), not in a live session")
    from dyno.control.plans import plan_named
    from dyno.rig.config import load_rig_for

    plan = plan_named(args.plan)  # a bad plan: one line naming file and field, before the screen is taken over
    rig_cfg = load_rig_for(getattr(args, "rig", None), sim=args.sim)  # (one line before the screen is taken over)
    from dyno.transports.budget import check_budget

    check_budget(rig_cfg)  # (so is a poll rate its link cannot carry)
    elf = getattr(args, "firmware_elf", None)
    if elf is not None and not args.sim:
        raise ConfigError("command line", "--firmware-elf", "the firmware ELF runs in the simulated rig only (--sim)")
    if elf is not None and not elf.is_file():
        raise ConfigError(str(elf), "--firmware-elf", "no such file (build it: make -C firmware sim)")
    if not args.sim:  # no GPIO / I2C here: one line and exit 2, not a traceback from inside the app
        from dyno.hw.preflight import check_rig_present

        check_rig_present(rig_cfg)
    if drills and not args.sim:
        raise ConfigError("command line", "--drill", "drills run on the simulated rig only (--sim)")
    if getattr(args, "mock_pins", False) and not args.sim:
        raise ConfigError("command line", "--mock-pins", "the mock pins drive the simulated rig only (--sim)")
    from dyno.cli.run_cmd import air_options

    sim_kw: dict = {}
    ambient, bad = air_options(args, sim_kw, "dyno ui")
    if bad:  # one line, exit 2, before the screen is taken over
        import sys

        print(bad, file=sys.stderr)
        return 2
    sim_params = None
    if sim_kw and args.sim:
        from dyno.sim.rig_params import RigParams

        sim_params = RigParams(**sim_kw)
    opts = LiveOptions(sim=args.sim, speed=args.speed, seed=args.seed, out_dir=args.out,
                       rig_path=getattr(args, "rig", None), calibration_path=args.calibration,
                       engine_map_path=args.engine_map, drills=drills, plan=plan,
                       mock_pins=bool(getattr(args, "mock_pins", False)), ambient=ambient, sim_params=sim_params,
                       firmware_elf=elf)
    web = None
    if args.web is not None or args.web_stop:  # before the screen is taken over: a bad --web is one line
        from dyno.web.attach import WebView

        web = WebView.start("dyno ui", args)
        if web is None:
            return 2
    app = (_with_web(LiveApp, web) if web is not None else LiveApp)(opts)
    try:
        app.run()
    finally:
        if web is not None:
            web.end()
    rc = app.return_code or 0
    session = getattr(app, "session", None)
    if session is not None and getattr(session, "ctx", None) is not None:
        runs = list(session.run_dirs)  # every run of the session (re-arm starts a new one), oldest first
    else:
        runs = [args.out] if args.out is not None else []
    for run_dir in runs:
        # each run's report was written in the background when its test ended; one quit before that is written now
        # (after a hang-up, SIGHUP: the terminal went, end now: no report, `dyno report RUN` writes it later)
        finish_run(run_dir, announce=True, only_if_missing=True, report=rc != 128 + 1)
    return rc


def _with_web(app_class, web):
    """The live app, its session also shown on the web (the feed hooks the session's poller when it starts;
    the URL is on the screen's message line and the title, as the terminal hides the stderr line)."""

    class WebLiveApp(app_class):
        def _start_session(self) -> None:
            super()._start_session()
            if self.session is None or self.session.closed:
                return
            import asyncio

            from dyno.web.feed import SessionSource

            web.attach(SessionSource(self.session), asyncio.get_running_loop())
            self._mode += f" │ web :{web.server.port}"
            self._show_run()
            self.say(f"web: {web.server.url}")

    return WebLiveApp


def finish_run(run_dir, *, announce: bool, only_if_missing: bool = False, report: bool = True) -> None:
    """Index an ended run and write its report.html (:func:`dyno.session.after.finish_run`), saying so: failures
    are one stderr line, never the exit code."""
    import sys

    from dyno.session.after import finish_run as finish

    def warn(prog):
        def say(line: str) -> None:
            try:
                print(f"{prog}: {line}", file=sys.stderr)
            except OSError:
                pass
        return say

    # (a report failure says "dyno run:", as it always has)
    there, path = finish(run_dir, warn_index=warn("dyno ui"), warn_report=warn("dyno run"),
                         only_if_missing=only_if_missing, report=report)
    if not there or not announce:
        return
    try:
        if path is not None:
            print(f"report: {path}")
            sys.stdout.flush()
        print(f"run: {run_dir}")
    except OSError:
        pass
