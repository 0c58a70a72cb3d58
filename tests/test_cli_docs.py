"""docs/cli.md is the parsers' own help (regenerate: `python -m dyno.cli.docgen > docs/cli.md`); every option says
what it is; `dyno run --help` names every drill and the forms of its time; every command takes --rig."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from dyno.cli import COMMANDS, command_parser, sub_parsers
from dyno.cli.docgen import render

pytestmark = pytest.mark.quick
ROOT = Path(__file__).resolve().parents[1]


def _all_parsers():
    for name in COMMANDS:
        _, parser = command_parser(name)
        yield parser
        yield from sub_parsers(parser)


def test_docs_cli_md_is_the_parsers_help():
    page = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    assert page == render(), ("docs/cli.md differs from the parsers' --help: run "
                              "`python -m dyno.cli.docgen > docs/cli.md`")


def test_every_option_of_every_command_has_help_text():
    missing = [f"{p.prog} {'/'.join(a.option_strings) or a.dest}" for p in _all_parsers() for a in p._actions
               if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))
               and not (a.help or "").strip() and a.help is not argparse.SUPPRESS]
    assert not missing, missing


def test_run_help_lists_every_drill_and_the_phase_forms():
    from dyno.session.drills import DRILLS, PHASES

    _, parser = command_parser("run")
    text = " ".join(parser.format_help().split()).replace("- ", "-")  # (argparse wraps lines at hyphens)
    for name in DRILLS:
        assert name in text, name
    for phase in PHASES:
        assert phase in text, phase
    for form in ("@12", "@loaded", "@loaded+2", "@after+1", "loop-stall:MS", "pi-freeze[:S]",
                 "hall-dead:primary|secondary|both", "--mock-pins"):
        assert form in text, form


def test_every_command_and_action_takes_rig(tmp_path):
    rig = tmp_path / "rig.toml"
    _, parser = command_parser("model")
    args = parser.parse_args(["point", "--rig", str(rig)])
    assert args.rig == rig or str(args.rig) == str(rig)
    for p in _all_parsers():
        assert "--rig" in p._option_string_actions, p.prog


def test_the_readme_has_one_short_line_per_command():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    long = [(n, len(x)) for n, x in enumerate(readme.splitlines(), 1) if len(x) > 400]
    assert not long, f"README lines over 400 characters: {long}"
    rows = [x for x in readme.splitlines() if x.startswith("| `dyno ")]
    for name in COMMANDS:
        assert any(x.startswith(f"| `dyno {name}") or f"`dyno {name}" in x.split("|")[1] for x in rows), name
    assert all(len(x) <= 200 for x in rows), [x for x in rows if len(x) > 200]
    assert "docs/cli.md" in readme
