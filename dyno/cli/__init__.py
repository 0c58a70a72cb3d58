"""The ``dyno`` command.

Each sub-command lives in its own module under ``dyno.cli`` exposing
``add_arguments(parser)`` and ``run(args) -> int``.  Modules are imported
lazily, only for the command being run, so ``dyno calibrate`` never pays for
the belt-model solver (python-can's lazy BACKENDS table, for commands).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util  # (find_spec: not loaded by "import importlib" outside an editable install)
import os
import sys

from dyno.errors import ConfigError, DynoError

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("dyno.cli.run_cmd", "run a steady-state test (simulated rig with --sim)"),
    "replay": ("dyno.cli.replay_cmd", "re-process a logged run (viewer, or --json)"),
    "export": ("dyno.cli.export_cmd", "export a run's points and streams (CSV, Parquet, MDF4)"),
    "report": ("dyno.cli.report_cmd", "(re)build a run's report.html: plots, points, faults, calibration"),
    "runs": ("dyno.cli.runs_cmd", "the run library: list and filter runs (reindex rebuilds the index)"),
    "compare": ("dyno.cli.compare_cmd", "compare runs side by side: curves, differences, tune diff"),
    "serve": ("dyno.cli.serve_cmd", "the run library in a browser: runs, reports, compare, downloads (read-only)"),
    "import-legacy": ("dyno.cli.legacy_cmd", "import a folder of the thesis rig's logs"),
    "model": ("dyno.cli.model_cmd", "belt-model library: point, sweep, study"),
    "firmware-sim": ("dyno.cli.firmware_sim_cmd", "run the real firmware ELF in simavr against the host"),
    "ui": ("dyno.cli.ui_cmd", "terminal UI for the rig (--sim for the simulated rig)"),
    "calibrate": ("dyno.cli.calibrate_cmd", "torque calibration wizard"),
    "doctor": ("dyno.cli.doctor_cmd", "check the rig's hardware and report what works"),
    "flash": ("dyno.cli.flash_cmd", "flash the Nano's firmware (the shipped build, or --hex FILE) with avrdude"),
    "init": ("dyno.cli.init_cmd", "write editable copies of the shipped rig files and calibration into DIR"),
    "shift-curve": ("dyno.cli.shift_curve_cmd", "predicted shift curve for a tune"),
    "tune": ("dyno.cli.tune_cmd", "tune advise: which catalogue parts reach target engagement/shift-out rpm"),
    "design": ("dyno.cli.design_cmd", "CVT design method (Arango & Munoz 2020)"),
    "arcvt": ("dyno.cli.arcvt_cmd", "AR-CVT actuation model (van Kerkhoven 2006)"),
}


class OneLineParser(argparse.ArgumentParser):
    """argparse with bad input reported on one line (what and what is expected), exit 2."""

    last_error: str | None = None

    def error(self, message: str):
        self.last_error = f"{self.prog}: error: {message} (see {self.prog} --help)"
        self.exit(2, self.last_error + "\n")


class ParagraphsFormatter(argparse.HelpFormatter):
    """argparse's help, with a description's or an epilog's paragraphs (blank-line separated) kept apart."""

    def _fill_text(self, text, width, indent):
        return "\n\n".join(super(ParagraphsFormatter, self)._fill_text(par, width, indent)
                             for par in text.split("\n\n"))


def number_in(lo: float, hi: float, *, integer: bool = False, lo_open: bool = False):
    """An argparse ``type``: a finite number in [lo, hi] (``(lo, hi]`` with ``lo_open``)."""
    import math

    def parse(text: str):
        try:
            v = int(text) if integer else float(text)
        except ValueError:
            v = None
        ok = v is not None and math.isfinite(v) and (v > lo if lo_open else v >= lo) and v <= hi
        if not ok:
            kind = "an integer" if integer else "a number"
            raise argparse.ArgumentTypeError(f"expected {kind} {'>' if lo_open else '>='} {lo:g} and <= {hi:g}, "
                                             f"got {text!r}")
        return v

    return parse


def command_available(name: str) -> bool:
    return importlib.util.find_spec(COMMANDS[name][0]) is not None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dyno", description="dyno: run a CVT dynamometer (or its simulated rig), analyse and compare the "
                                 "runs, and set them beside the belt model. `dyno COMMAND --help` for each.")
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        if not command_available(name):
            continue
        sub.add_parser(name, help=help_text, add_help=False)
    return parser


#: exit codes for a closed output pipe and Ctrl+C outside a test: 128 + the signal's number, as a shell reports
EXIT_BROKEN_PIPE, EXIT_INTERRUPTED = 128 + 13, 128 + 2
EXIT_HANGUP = 128 + 1  # SIGHUP: the command's terminal went (docs/safety.md)


def main(argv: list[str] | None = None) -> int:
    """Run one command.  `dyno ... | head` and Ctrl+C end quietly (one line at most), never with a traceback."""
    as_program = argv is None  # (tests call main(argv) in their own process: never ended from here)
    argv = list(sys.argv[1:] if argv is None else argv)
    name = argv[0] if argv and argv[0] in COMMANDS else None
    try:
        rc = _dispatch(argv)
    except BrokenPipeError:  # the reader went away mid-output (`| head`): nothing more to say to it
        _detach_stdout()
        return EXIT_BROKEN_PIPE
    except KeyboardInterrupt:  # Ctrl+C outside a test (a test handles its signals itself: safe state first)
        _detach_stdout()
        print(f"dyno{' ' + name if name else ''}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    try:
        sys.stdout.flush()
    except BrokenPipeError:  # the command did its job; only the tail of its output was not read
        _detach_stdout()
    except OSError:  # a terminal that went (EIO)
        pass
    if as_program and rc == EXIT_HANGUP:
        _end_now(rc)
    return rc


def _end_now(rc: int) -> None:
    """The terminal went (SIGHUP) and the command has put the rig in its safe state and closed its record:
    end now.  The interpreter's own finalisation (module teardown and collection: 0.3-0.8 s measured on a
    loaded 2-core machine) is skipped; the atexit hooks (gpiozero closing its pins) still run first."""
    import atexit

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(rc)


def _detach_stdout() -> None:
    # Point stdout at /dev/null so the interpreter's own flush at exit cannot raise again (Python docs,
    # "Note on SIGPIPE").
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


def _json_error(line: str, rc: int) -> None:
    """--json asked: a script reading stdout gets a JSON document on a refusal too (the line stays on stderr)."""
    import json

    try:
        print(json.dumps({"error": line, "exit_code": rc}))
    except OSError:
        pass


def _error(line: str, rc: int, as_json: bool) -> int:
    print(line, file=sys.stderr)
    if as_json:
        _json_error(line, rc)
    return rc


def command_parser(name: str):
    """(module, parser) of ``dyno NAME``: what runs it and what its ``--help`` says (docs/cli.md is made from these)."""
    from dyno.cli.epilogs import EPILOGS

    mod = importlib.import_module(COMMANDS[name][0])
    parser = OneLineParser(prog=f"dyno {name}", description=COMMANDS[name][1], epilog=EPILOGS.get(name),
                           formatter_class=ParagraphsFormatter)
    mod.add_arguments(parser)
    for p in [parser, *sub_parsers(parser)]:
        if "--rig" not in p._option_string_actions:
            # every command (and every action of one, `dyno model point`) takes --rig PATH (the rig
            # description), even where it only records it, so scripts can pass it uniformly
            from dyno.rig.locate import add_rig_argument

            add_rig_argument(p)
    return mod, parser


def sub_parsers(parser) -> list:
    """The parsers of a command's actions (``dyno model point``, ...), in the order they were added."""
    return [p for a in parser._actions if isinstance(a, argparse._SubParsersAction) for p in a.choices.values()]


def _dispatch(argv: list[str]) -> int:
    if argv and argv[0] in COMMANDS and command_available(argv[0]):
        name = argv[0]
        mod, parser = command_parser(name)
        try:
            args = parser.parse_args(argv[1:])
        except SystemExit as exc:  # --help, or a bad argument (already reported on one line)
            if exc.code and parser.last_error and "--json" in argv[1:]:
                _json_error(parser.last_error, int(exc.code))
            return int(exc.code or 0)
        as_json = bool(getattr(args, "json", False))
        try:
            return int(mod.run(args) or 0)
        except ConfigError as exc:
            return _error(f"dyno {name}: error: {exc}", 2, as_json)
        except DynoError as exc:
            return _error(f"dyno {name}: error: {exc}", 1, as_json)
        except UnicodeDecodeError as exc:  # a binary or non-UTF-8 file where text was expected
            return _error(f"dyno {name}: error: a file is not UTF-8 text ({exc.reason} at byte {exc.start})", 2,
                          as_json)
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError) as exc:
            # an input path that is not a readable file (loaders name theirs; this is the net)
            return _error(f"dyno {name}: error: {exc.filename}: {exc.strerror}", 2, as_json)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.version:
        from dyno import __version__

        print(__version__)
        return 0
    parser.print_help()
    return 0 if not argv else 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
