"""What each command's ``--help`` says after its options: what it prints, its exit codes, the ways to use it.

One place, beside the parsers (:func:`dyno.cli.command_parser` hangs each under its command): docs/cli.md is made
from the help (``python -m dyno.cli.docgen > docs/cli.md``), README.md keeps one line per command.  Paragraphs are
separated by a blank line; argparse fills each to the terminal's width.
"""

from __future__ import annotations

EXIT_CODES = ("Exit codes: 0 done, 1 a failure the command names, 2 bad input (one line naming the file and field; "
              "nothing changed), 3 a test aborted to the safe state, 128+N signal N (130 Ctrl+C outside a test, "
              "141 a closed output pipe: `dyno ... | head`). With --json every refusal is a document too: "
              '{"error": LINE, "exit_code": N} (the line also on stderr).')

EPILOGS: dict[str, str] = {
    "run": f"""\
`dyno run --sim --headless --json [--seed S] [--fault-rate P] [--speed N] [--out DIR]`: a full test, one JSON \
document, with `link` (the firmware link's transport, clock, poll rate and its busiest second's share, planned and \
measured: `link_busy` in its warnings above 60 % measured), `poll_rates` (the rate held and the intervals' jitter at \
each rate polled), `pace` with --speed N (the pace held in wall time). A rig file whose busiest second (its polls, \
MORE bursts, retries, boot commands, thermometer) would take over 60 % of its link polls at the fastest rate that \
fits, saying so on one line naming `poll_hz` (`derate = false`, or no rate fits: refused naming `poll_hz`). \
Without --json a \
terminal shows a status line (state, point n/~N, ETA) and ends with the points table (each efficiency with its \
±CI95, ±U95 and interval95 %, the speed ratio, where P_in comes from; the term that dominates U95), the air and the \
path of the run's report.html.

Plans (--plan; `dyno ui --plan` too): speed-hold (the default: closed-loop speed setpoints, each point to a 95 % CI \
of ±1 pp: 19 points in ~90-100 s of test time, bench/bench_test_time.py), thesis-step (the thesis's open-loop \
steps), torque-hold, engine-hold, sweep, or a plan file (docs/control.md). engagement: engagement, lock-up and \
shift-out rpm (and shift-out vs load), full-shift ratio, each with its 95 % interval, beside the tune's prediction \
(and `dyno tune advise`'s, on a tune it proposed). drive-grid (with a part-throttle --engine-map, e.g. \
calibration/engine_maps/baja-10hp-representative-part-throttle.csv): throttle x secondary-speed grid, unreachable \
cells named; each point records its throttle_frac (docs/analysis.md). coast-down: the driven side's parasitic loss \
torque vs speed -> driven_loss.json, which --driven-loss adds back to the efficiency.

The air: the engine map is taken to the day by SAE J1349 (the BME280 the shipped rig.toml [ambient] declares: one \
that does not answer refuses the run, exit 2; or --ambient; sensor = "none" and neither: "uncorrected"). Each \
point's efficiency_interval95 [low, high] (statistical + calibration + map + air + driveline; asymmetric where a \
term is; at most 1) and its half-width efficiency_u95; the JSON's u95_terms says what each term assumes, and `dyno compare` \
cancels what two runs share. The simulated rig is its own engine, sensor and day, unlike what the host assumes \
(--sim-ideal: perfect knowledge); bench/bench_uncertainty.py judges the interval over 60 of them per world and path \
(docs/analysis.md).

`--rig hardware/rig-input-torque.toml`: a rig with an engine-side torque channel (a load cell on the engine \
cradle): each point's efficiency from two measured powers, its own efficiency_u95, the map's figure beside it \
(efficiency_source); bench/bench_input_torque.py judges both paths (docs/analysis.md, hardware/README.md).

Drills (--drill, docs/safety.md): bus-lost@30, overtemp@60, loop-stall:800@40, pi-freeze@loaded+2 (the Pi stops \
dead and the Nano's run-enable cuts the engine; outputs.engine_cut_by says who did), overspeed@after+1. With \
--mock-pins through the Pi's own output code over a twin of the rig's wiring (GpioActuators, the E-stop input and \
the watchdog on gpiozero's MockFactory). The JSON's outputs are the physics' (brake_position_mm, released_at_s, \
release_s); rig_safe is true only with the pads off the rotor, driver_agrees says whether the Pi's code thinks so \
too. The wiring drills need --mock-pins and a rig file declaring the switch they act on (pins.brake_released_input, \
pins.estop_input).

--web [ADDR:PORT]: a read-only live view in a browser (prints web: http://HOST:PORT/?token=T; /api/state JSON; an \
optional software STOP, not an emergency stop; pip install -e '.[web]'; docs/web.md).

{EXIT_CODES}""",
    "ui": """\
The rig's terminal UI (80x24 over SSH, keyboard only): g GO (it says what the plan will move), space or Ctrl+C \
E-STOP, p pause, m manual with [ ] jog, 1-3 plots, o the belt-model overlay, r re-arm after a test (a new run \
directory), q quit. When a test ends the UI does what `dyno run` does after its test, through the same code: the \
torque zero read at rest (the torque_zero record), the summary and its safety document (drills, true-time \
latencies, physical outputs), the log closed and report.html written, while the screen stays up. The engagement \
and coast-down plans show their figures on screen when they end (4). --drill and --mock-pins as in `dyno run` \
(pi-freeze only there); --web as in `dyno run`. docs/ui.md.""",
    "replay": "Re-processes a logged run with the current analysis (another --calibration or --engine-map, a "
              "--driven-loss, a --measured-map built from an input torque channel), as a viewer or with --json.",
    "report": "Every `dyno run` and `dyno ui` run writes its report.html; this rebuilds it (legacy imports too). "
              "--model full draws the full belt model where its cache has the points.",
    "export": "Points and raw streams as CSV, or one Parquet / ASAM MDF4 file (pip install '.[export]').",
    "runs": "The run library: every run indexed with its tune (SQLite in runs/ or $DYNO_RUNS_DIR); "
            "`dyno runs reindex` rebuilds the index (docs/library.md).",
    "compare": "Runs side by side: curves, differences with their uncertainty (significant or not; the terms two "
               "runs share cancel, each stated), tune diff; terminal and HTML (docs/library.md).",
    "serve": "The run library in a browser, read-only: runs by tune, date and state, reports, compare, downloads "
             "(docs/web.md).",
    "calibrate": """\
The torque-calibration wizard, under the same safety monitor as a test (--mock-pins: the rig's outputs through the \
Pi's own code on the wiring twin): known weights on the brake rotor (--channel output, the default) or on the \
engine cradle's arm (input: the rig file declares [input_torque], e.g. --rig hardware/rig-input-torque.toml); at \
least 3 loads, a zero check before and after, R², each channel its own history. --repeats N applies the loads N \
times and shows the slope's spread (about 0.4 % on both channels brings the map-free efficiency's U95 to ±2 pp; \
docs/ui.md).""",
    "tune": """\
`dyno tune advise RUN [RUN...] --target engagement=RPM --target shift_out=RPM`: which parts of the catalogue \
(calibration/parts/*.toml) to fit: calibrates the parts' effective values from engagement runs, searches every \
tune of at most N changed parts, ranks them with predicted figures ± U95, writes tune files for `dyno run --tune` \
and advice.html; `dyno runs` then shows "advised: predicted X ± u, measured Y" (docs/tuning.md). \
`dyno run --sim --sim-tune-deviation 0.1` makes the simulated parts differ from their labels.""",
    "firmware-sim": """\
The real firmware's ELF in simavr against the real host: build both with `make -C firmware sim` (gcc-avr avr-libc \
binutils-avr simavr libsimavr-dev libelf-dev), then `dyno firmware-sim --elf firmware/build/dyno_nano.elf \
--seconds 2`. --input-hz 125: the second AD7171 of the engine-side torque channel on D8/D9. The text output rounds \
its figures; --json keeps every digit (docs/firmware.md).""",
    "doctor": """\
On the rig: the link budget (the busiest second planned; above 60 %: the rate a run derates to, or FAIL where none \
fits), the I²C bus, the firmware and its run-enable (the Nano's D7: present, armed by dyno at \
every boot), a few seconds of data frames channel by channel (Hall edges: it asks you to turn a shaft that shows \
none; the converter's rate and codes; the link's NACK/CRC/stretch counters: one FAIL line naming the channel and \
its wire; the busiest second of those polls measured, a WARN above 60 %), the thermometer, the E-stop input. --toggle moves the outputs (watchdog running) and checks the end \
switch against a measured stroke (a pass clears a standing end-switch fault, which otherwise refuses GO and re-arm \
across restarts; with K3 fitted, as shipped, the step is skipped and said so: hardware/README.md). --sim: the same \
on the simulated rig (--mock-pins through the wiring twin; --drill a fault from the start: hall-dead:primary, \
adc-stuck, endswitch-stuck-closed, ...). Exit 0 ready, 1 a FAIL line, 2 bad input.""",
    "model": "point: the full steady belt model at the thesis's Table 6.1 case. sweep, study: the operating-range "
             "sweep and Section 7 parameter studies as tasks on a local process pool or a Dask cluster "
             "(--jobs N, --scheduler ADDRESS; pip install -e '.[cluster]'), cached and resumable; CSV, Parquet, PNG. "
             "overlay RUN: the belt model at every point of a run. inverse RUN: each point's geometric ratio and "
             "belt slip. docs/belt-model.md.",
    "shift-curve": "The predicted shift curve of a CVT tune, overlaid on a run's points with --run.",
    "design": "The numerical CVT design method (Arango & Munoz 2020) from a requirements file.",
    "arcvt": "The AR-CVT actuation model (van Kerkhoven 2006).",
    "import-legacy": "A folder of the thesis rig's logs as a run (docs/legacy-import.md).",
}
