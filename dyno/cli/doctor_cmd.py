"""``dyno doctor``: check the rig's hardware and report what works (parse -> spec -> diagnose -> print).

The diagnosis is library code (:mod:`dyno.hw.doctor`); this is its command line.  Exit status: 0 all essential
checks pass, 1 an essential check failed, 2 the rig description is invalid (the CLI's ConfigError handling).
"""

from __future__ import annotations

import sys

from dyno.hw.doctor import run_diagnosis
from dyno.session.doctor_rig import doctor_spec
from dyno.rig.locate import add_rig_argument
from dyno.rig.config import load_rig_for


def add_arguments(parser) -> None:
    add_rig_argument(parser)
    parser.add_argument("--toggle", action="store_true",
                        help="also exercise outputs: pulse the Arduino reset, step the brake out and back")
    parser.add_argument("--transport", choices=("i2c", "serial"), default=None,
                        help="firmware link (default: the rig file's)")
    parser.add_argument("--sim", action="store_true", help="diagnose the simulated rig (no hardware)")
    parser.add_argument("--mock-pins", action="store_true",
                        help="--sim: the output checks (as --toggle) through the Pi's own code on the wiring twin")
    parser.add_argument("--drill", action="append", default=[], metavar="NAME[:ARG]",
                        help="--sim: a fault there from the start (no @T): hall-dead:primary|secondary|both, "
                             "adc-stuck, adc-error, thermometer-lost; with --mock-pins also endswitch-stuck-closed, "
                             "endswitch-stuck-open, endswitch-bounce")


def run(args) -> int:
    cfg = load_rig_for(args.rig, sim=args.sim)  # real hardware: never the shipped rig file (dyno.rig.locate)
    spec = doctor_spec(cfg, sim=args.sim, mock_pins=args.mock_pins, drills=args.drill, toggle=args.toggle,
                       transport_kind=args.transport, interactive=not args.sim and sys.stdin.isatty())
    print(f"dyno doctor: {cfg.path}" + (" (simulated rig)" if args.sim else ""), flush=True)
    report = run_diagnosis(spec)
    print(report.render())
    sys.stdout.flush()
    return 0 if report.ok else 1
