"""``dyno firmware-sim``: run the real firmware ELF in simavr against the real host code (parse -> spec ->
:func:`dyno.session.firmware_sim.simulate` -> print).  What it does and its exit status: :mod:`dyno.session.firmware_sim`."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from dyno.cli import number_in
from dyno.session.firmware_sim import RESET_CAUSES, FirmwareSimSpec, check_spec, simulate
from dyno.transports.simavr import ALL_FAULT_KINDS, FAULT_KINDS


def _reset_at(text: str) -> tuple:
    """--reset-at S[:CAUSE] -> (seconds, MCUSR)."""
    import argparse

    t, _, cause = text.partition(":")
    cause = cause or "watchdog"
    if cause not in RESET_CAUSES:
        raise argparse.ArgumentTypeError(f"cause {cause!r} unknown; expected one of {', '.join(RESET_CAUSES)}")
    return number_in(0.0, 3600.0)(t), RESET_CAUSES[cause]


def add_arguments(parser) -> None:
    parser.add_argument("--elf", required=True, help="firmware ELF to run (any ATmega328P sketch)")
    parser.add_argument("--protocol", choices=("v2", "v1", "v0"), default="v2", help="the protocol the firmware speaks (default v2)")
    parser.add_argument("--transport", choices=("i2c", "serial"), default="i2c",
                        help="the host's link to the MCU: I2C (TWI) or USB serial (UART0, COBS)")
    parser.add_argument("--primary-rpm", type=number_in(0.0, 30000.0), default=3800.0,
                        help="the primary Hall signal's speed (default 3800 rpm)")
    parser.add_argument("--secondary-rpm", type=number_in(0.0, 30000.0), default=7600.0,
                        help="the secondary Hall signal's speed (default 7600 rpm)")
    parser.add_argument("--adc-code", type=lambda s: int(s, 0), default=35145,
                        help="the torque ADC's code the simulated converter returns (default 35145)")
    parser.add_argument("--adc-status", type=lambda s: int(s, 0), default=0x05,
                        help="AD7171 status byte clocked after the data (default 0x05)")
    parser.add_argument("--adc-error-every", type=number_in(0, 1_000_000, integer=True), default=0,
                        help="set the AD7171 error bit on every Nth conversion (0: never)")
    parser.add_argument("--adc-hz", type=number_in(1.0, 1000.0), default=125.0,
                        help="the torque ADC's conversion rate (default 125 Hz)")
    parser.add_argument("--input-hz", type=number_in(0.0, 1000.0), default=0.0,
                        help="fit the engine-side input torque AD7171 (D8/D9) at this rate; the host enables "
                             "it (protocol v2 CAPS / SET_CHANNELS) and the report adds its events (0: not fitted)")
    parser.add_argument("--seconds", type=number_in(0.0, 3600.0, lo_open=True), default=5.0,
                        help="simulated seconds of signal")
    parser.add_argument("--bounce", action="store_true",
                        help="the Hall line rings at release: two 40 us pulses 150 and 700 us after each pulse")
    parser.add_argument("--glitch-hz", type=number_in(0.0, 100_000.0), default=0.0,
                        help="Poisson rate of glitches (ignition spikes) on each Hall line, per second")
    parser.add_argument("--glitch-us", type=number_in(0.0, 10_000.0, lo_open=True), default=20.0,
                        help="glitch width in us (default 20)")
    parser.add_argument("--fault-rate", type=number_in(0.0, 0.5), default=0.0,
                        help="probability that a transfer is corrupted between harness and host")
    parser.add_argument("--fault-kinds", default=",".join(FAULT_KINDS),
                        help=f"comma list from {','.join(ALL_FAULT_KINDS)} (default: all but abort)")
    parser.add_argument("--seed", type=number_in(0, 2**32 - 1, integer=True), default=1,
                        help="seed of the injected faults and jitter (default 1)")
    parser.add_argument("--poll-hz", type=number_in(0.0, 2000.0, lo_open=True), default=150.0,
                        help="the host's poll rate (default 150 Hz)")
    parser.add_argument("--poll-jitter", type=number_in(0.0, 1.0), default=0.0,
                        help="poll at random intervals: each uniform within +-J of the period (0..1)")
    parser.add_argument("--max-burst", type=number_in(1, 1000, integer=True), default=8,
                        help="reads per poll while the device says MORE (the Poller's default)")
    parser.add_argument("--i2c-khz", type=number_in(10, 1000, integer=True), default=100,
                        help="the I2C bus clock (default 100 kHz)")
    parser.add_argument("--drain-s", type=number_in(0.0, 60.0), default=0.3,
                        help="keep polling this long after the signals stop")
    parser.add_argument("--reset-at", type=_reset_at, action="append", default=None, metavar="S[:CAUSE]",
                        help="reset the MCU at this simulated second, cause watchdog (default), external or "
                             "brown-out (repeatable)")
    parser.add_argument("--harness", default=None, help="harness binary (default firmware/build/harness)")
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    _supervisor_arguments(parser)  # --rig, --host-stop-at, --no-limits, --enable-model (issue 37)


def _supervisor_arguments(parser) -> None:
    from dyno.rig.locate import add_rig_argument

    add_rig_argument(parser)  # --rig PATH: its [limits] arm the run-enable at every boot
    parser.add_argument("--host-stop-at", type=number_in(0.0, 3600.0), default=None, metavar="S",
                        help="the host stops polling at S simulated seconds (the simulation goes on to --seconds; "
                             "the host reads what the device kept after the drain)")
    parser.add_argument("--rearm-at", type=number_in(0.0, 3600.0), default=None, metavar="S",
                        help="the operator re-arms the run-enable at S simulated seconds (after a Nano reset the "
                             "new boot stays cut until then)")
    parser.add_argument("--pulse-at", type=number_in(0.0, 3600.0), default=None, metavar="S",
                        help="the host's kill-path probe: PULSE_RUN_ENABLE at S simulated seconds (D7 off for "
                             "--pulse-ms, then on again, unlatched)")
    parser.add_argument("--pulse-ms", type=number_in(1, 1000, integer=True), default=100, metavar="MS",
                        help="the probe's pulse length, 1 ... 1000 ms (default 100)")
    parser.add_argument("--no-limits", action="store_true",
                        help="never send the rig file's limits (SET_SUPERVISOR): the run-enable stays off")
    parser.add_argument("--enable-model", choices=("auto", "static", "pump"), default="auto",
                        help="how the harness reads D7: a static level (watchdog build), a charge pump's pulse "
                             "train (old-bootloader build), or auto-detected (default)")


def _fig(x, spec: str) -> str:
    """A figure to a sensible precision (the JSON keeps every digit); "-" for none."""
    return "-" if not isinstance(x, (int, float)) else format(x, spec)


def spec_from_args(args) -> FirmwareSimSpec:
    """The command line's options as the library's typed spec (the same names)."""
    names = {f.name for f in dataclasses.fields(FirmwareSimSpec)}
    kw = {k: v for k, v in vars(args).items() if k in names}
    kw["reset_at"] = tuple(args.reset_at or ())
    return FirmwareSimSpec(**kw)


def run(args) -> int:
    from dyno.errors import ConfigError

    spec = spec_from_args(args)
    check_spec(spec)
    if not Path(args.elf).is_file():  # bad input, not a harness failure: exit 2 with the build step
        raise ConfigError(args.elf, "--elf", "no such firmware ELF (build it with `make -C firmware sim`)")
    report = simulate(spec)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        ev = report["events"]
        err = report.get("rpm_error_pct") or {}
        print(f"{report['protocol']} {report['elf']}: {_fig(report['seconds'], '.3g')} s simulated "
              f"in {_fig(report['wall_s'], '.1f')} s wall")
        print(f"  rpm primary {_fig(report['rpm_primary'], '.2f')} ({_fig(err.get('primary'), '+.3f')} %), "
              f"secondary {_fig(report['rpm_secondary'], '.2f')} ({_fig(err.get('secondary'), '+.3f')} %), "
              f"adc mean {_fig(report['adc_mean'], '.1f')}")
        for name, ch in ev.items():
            print(f"  {name}: {ch['received']} received of {ch['expected']} generated")
        fr = report["frames"]
        print(f"  frames: {fr['read']} read, {fr['accepted']} accepted, rejected {fr['rejected']}, "
              f"transport errors {fr['transport_errors']}; events lost {report['events_lost']}")
        sv = report.get("supervisor")
        if sv:
            state = "on" if sv["off_at_s"] is None else f"off at {sv['off_at_s']:.4f} s ({sv['cause']})"
            print(f"  run-enable (D7, {sv['model']}): {state}; on at {_fig(sv['on_at_s'], '.4f')} s; "
                  f"limits sent at {_fig(sv['limits_sent_at_s'], '.4f')} s")
    return 0 if report["ok"] else 1
