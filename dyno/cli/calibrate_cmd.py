"""dyno calibrate: the known-weights torque calibration wizard."""

from __future__ import annotations

from pathlib import Path

from dyno.cli import number_in

SIM_HISTORY = Path("runs") / "sim_torque_calibration.csv"


def add_arguments(p) -> None:
    p.add_argument("--sim", action="store_true",
                   help="the simulated rig in its calibration fixture (hidden true gain and offset)")
    p.add_argument("--samples", type=number_in(2, 100_000, integer=True), default=500, help="ADC samples per load step (default 500)")
    p.add_argument("--settle-samples", type=number_in(0, 100_000, integer=True), default=125,
                   help="samples dropped at the start of each step while the load settles (default 125)")
    p.add_argument("--history", type=Path, default=None,
                   help="calibration history CSV to append to (default: the rig's; with --sim "
                        f"{SIM_HISTORY}, never the rig's)")
    p.add_argument("--radius", type=number_in(0.01, 2.0), default=0.15, help="rope radius on the brake rotor, m")
    p.add_argument("--masses", default="5,10,20,30,40", help="masses in kg, comma-separated")
    p.add_argument("--seed", type=number_in(0, 2**32 - 1, integer=True), default=0, help="simulation seed")
    p.add_argument("--speed", type=number_in(0.0, 1000.0, lo_open=True), default=1.0, help="simulation pace, multiple of real time")
    p.add_argument("--drill", action="append", default=[], metavar="NAME[:ARG]@T",
                   help="fault drill at T simulated seconds from the first frame (--sim only): device-reset, "
                        "adc-error, adc-stuck, bus-lost, loop-stall:MS, sigint, sigterm, sighup (docs/safety.md)")
    from dyno.rigconfig import add_rig_argument

    add_rig_argument(p)


def run(args) -> int:
    from dyno.ui.calibrate_app import CalibrateOptions, main

    if args.samples < 2 or args.settle_samples < 0 or not args.speed > 0:
        raise SystemExit("dyno calibrate: --samples >= 2, --settle-samples >= 0, --speed > 0")
    from dyno.drills import parse_drill
    from dyno.errors import ConfigError

    drills = [parse_drill(d, engine=False) for d in args.drill]
    from dyno.rigconfig import load_rig

    rig_cfg = load_rig(getattr(args, "rig", None))  # a bad rig file: one line before the screen is taken over
    if not args.sim:  # no GPIO / I2C here: one line and exit 2, not a traceback from inside the app
        from dyno.hw.preflight import check_rig_present

        check_rig_present(rig_cfg)
    if drills and not args.sim:
        raise ConfigError("command line", "--drill", "drills run on the simulated rig only (--sim)")
    history = args.history
    if history is None:
        if args.sim:
            history = SIM_HISTORY  # a simulated calibration must never land in the rig's history
        else:  # pragma: no cover - rig only
            from dyno.app import DEFAULT_CALIBRATION

            history = DEFAULT_CALIBRATION
    Path(history).parent.mkdir(parents=True, exist_ok=True)
    opts = CalibrateOptions(sim=args.sim, seed=args.seed, speed=args.speed, n_samples=args.samples,
                            settle_samples=args.settle_samples, history_path=Path(history),
                            rig_path=getattr(args, "rig", None), radius_m=args.radius, masses=args.masses,
                            drills=drills)
    return main(opts)
