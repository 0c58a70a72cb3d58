"""dyno calibrate: the known-weights torque calibration wizard, for either torque channel."""

from __future__ import annotations

from pathlib import Path

from dyno.cli import number_in

SIM_HISTORY = Path("runs") / "sim_torque_calibration.csv"
SIM_INPUT_HISTORY = Path("runs") / "sim_input_torque_calibration.csv"


def add_arguments(p) -> None:
    p.add_argument("--sim", action="store_true",
                   help="the simulated rig in its calibration fixture (hidden true gain and offset)")
    p.add_argument("--channel", choices=("output", "input"), default="output",
                   help="output: the brake-side torque channel (masses on a rope round the brake rotor; the "
                        "default); input: the engine-side channel (masses on the engine cradle's arm; rig.toml "
                        "[input_torque], e.g. --rig hardware/rig-input-torque.toml)")
    p.add_argument("--samples", type=number_in(2, 100_000, integer=True), default=500, help="ADC samples per load step (default 500)")
    p.add_argument("--settle-samples", type=number_in(0, 100_000, integer=True), default=125,
                   help="samples dropped at the start of each step while the load settles (default 125)")
    p.add_argument("--history", type=Path, default=None,
                   help="calibration history CSV to append to (default: the channel's own, "
                        "calibration/torque_calibration.csv or rig.toml [input_torque] calibration; with --sim "
                        f"{SIM_HISTORY} or {SIM_INPUT_HISTORY}, never the rig's)")
    p.add_argument("--radius", type=number_in(0.01, 2.0), default=None,
                   help="rope radius on the brake rotor (default 0.15), or with --channel input the cradle arm's "
                        "length (default 0.2), m")
    p.add_argument("--masses", default=None,
                   help="masses in kg, comma-separated, at least 3 distinct (default 5,10,20,30,40; "
                        "--channel input 2,4,6,8,10)")
    p.add_argument("--repeats", type=number_in(1, 20, integer=True), default=1,
                   help="apply the whole load sequence (loading and unloading) N times: the slope's spread "
                        "across them is shown as the calibration's reproducibility (0.4 %% on both channels "
                        "brings the map-free efficiency's U95 to ~2 pp); default 1")
    p.add_argument("--seed", type=number_in(0, 2**32 - 1, integer=True), default=0, help="simulation seed")
    p.add_argument("--speed", type=number_in(0.0, 1000.0, lo_open=True), default=1.0, help="simulation pace, multiple of real time")
    p.add_argument("--mock-pins", action="store_true",
                   help="--sim: the rig's outputs through the Pi's own code (GpioActuators, E-stop input, watchdog "
                        "thread) on the wiring twin (docs/safety.md)")
    p.add_argument("--firmware-elf", type=Path, default=None, metavar="PATH",
                   help="--sim: the Nano's real firmware ELF in simavr as the fixture's Nano (firmware in the loop)")
    p.add_argument("--drill", action="append", default=[], metavar="NAME[:ARG]@T",
                   help="fault drill at T simulated seconds from the first frame (--sim only): device-reset, "
                        "adc-error, adc-stuck, bus-lost, loop-stall:MS, sigint, sigterm, sighup (docs/safety.md)")
    from dyno.rig.locate import add_rig_argument

    add_rig_argument(p)


def _check_masses(text: str) -> None:
    """The masses before the screen is taken over: one line naming --masses, exit 2 (the wizard's rules)."""
    from dyno.errors import ConfigError
    from dyno.analysis.calibration import check_loads
    from dyno.ui.calibration_wizard import parse_masses

    try:
        masses = parse_masses(text)
    except ValueError as exc:
        raise ConfigError("command line", "--masses", str(exc)) from None
    problems = check_loads(masses)
    if problems:
        raise ConfigError("command line", "--masses", "; ".join(problems))


def run(args) -> int:
    from dyno.ui.calibrate_app import (DEFAULT_INPUT_ARM_M, DEFAULT_INPUT_MASSES, DEFAULT_MASSES, DEFAULT_RADIUS_M,
                                       CalibrateOptions, main)

    if args.samples < 2 or args.settle_samples < 0 or not args.speed > 0:
        raise SystemExit("dyno calibrate: --samples >= 2, --settle-samples >= 0, --speed > 0")
    from dyno.session.drills import parse_drill
    from dyno.errors import ConfigError

    drills = [parse_drill(d, engine=False) for d in args.drill]
    from dyno.rig.config import load_rig_for

    rig_cfg = load_rig_for(getattr(args, "rig", None), sim=args.sim)  # (one line before the screen is taken over)
    from dyno.transports.budget import check_budget

    check_budget(rig_cfg)  # (so is a poll rate its link cannot carry)
    inp = args.channel == "input"
    if inp and getattr(rig_cfg, "input_torque", None) is None:
        raise ConfigError("command line", "--channel", f"input: the rig file {rig_cfg.path} declares no input "
                          "torque channel (rig.toml [input_torque], e.g. --rig hardware/rig-input-torque.toml)")
    if inp and not args.sim and rig_cfg.protocol != "v2":  # (the simulated fixture always speaks v2)
        raise ConfigError(rig_cfg.path, "protocol", f'"v2" for --channel input: the engine-side converter is a '
                          f'v2 extension (docs/protocol.md), the rig file says "{rig_cfg.protocol}"')
    masses = args.masses if args.masses is not None else (DEFAULT_INPUT_MASSES if inp else DEFAULT_MASSES)
    radius = args.radius if args.radius is not None else (DEFAULT_INPUT_ARM_M if inp else DEFAULT_RADIUS_M)
    _check_masses(masses)
    if args.firmware_elf is not None and not args.sim:
        raise ConfigError("command line", "--firmware-elf", "the firmware ELF runs in the simulated rig only (--sim)")
    if args.firmware_elf is not None and not args.firmware_elf.is_file():
        raise ConfigError(str(args.firmware_elf), "--firmware-elf", "no such file (build it: make -C firmware sim)")
    if not args.sim:  # no GPIO / I2C here: one line and exit 2, not a traceback from inside the app
        from dyno.hw.preflight import check_rig_present

        check_rig_present(rig_cfg)
    if drills and not args.sim:
        raise ConfigError("command line", "--drill", "drills run on the simulated rig only (--sim)")
    if args.mock_pins and not args.sim:
        raise ConfigError("command line", "--mock-pins", "the wiring twin drives the simulated rig only (--sim)")
    in_force = None
    if inp:
        from dyno.session.input_channel import calibration_path

        in_force = calibration_path(rig_cfg.input_torque)  # the channel's history the runs read
    else:
        from dyno.session.calibration_files import calibration_in_force

        in_force = calibration_in_force()
    history = args.history
    if history is None:
        if args.sim:  # a simulated calibration must never land in the rig's history
            history = SIM_INPUT_HISTORY if inp else SIM_HISTORY
        else:  # pragma: no cover - rig only
            from dyno.session.calibration_files import history_to_append, is_shipped

            # the shipped history is never written: the state directory's copy is (docs/install-pi.md)
            history = history_to_append(in_force.name) if is_shipped(in_force) else in_force
    history = Path(history)
    if history.exists():  # a malformed history: one line naming its file, line and field; nothing written
        from dyno.analysis.calibration_history import load_history

        load_history(history)
    history.parent.mkdir(parents=True, exist_ok=True)
    opts = CalibrateOptions(sim=args.sim, seed=args.seed, speed=args.speed, n_samples=args.samples,
                            settle_samples=args.settle_samples, history_path=history,
                            rig_path=getattr(args, "rig", None), radius_m=radius, masses=masses,
                            drills=drills, channel=args.channel, repeats=args.repeats, in_force_path=in_force,
                            mock_pins=args.mock_pins, firmware_elf=args.firmware_elf)
    return main(opts)
