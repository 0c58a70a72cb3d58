"""docs/cli.md, made from the parsers' own help: ``python -m dyno.cli.docgen > docs/cli.md``.

A test (tests/test_cli_docs.py) fails when docs/cli.md differs from what this prints: a new flag or drill is in
the page once the generator is run again, and never only in one of the two.
"""

from __future__ import annotations

import os
import sys

#: the help's width in the page (fixed: the page must not depend on the terminal it was made in)
WIDTH_COLUMNS = 100

HEAD = """# The `dyno` commands

Every command's `--help`, as the program prints it (generated: `python -m dyno.cli.docgen > docs/cli.md`; a test
fails when this page and the parsers differ). README.md has one line per command; the guides under docs/ say
why and how.
"""


def render() -> str:
    """The page: the top-level help, then each command's (and each action's, `dyno model point`)."""
    from dyno.cli import COMMANDS, command_available, build_parser, command_parser, sub_parsers

    before = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(WIDTH_COLUMNS + 2)  # (argparse wraps at the terminal's width less 2)
    try:
        out = [HEAD, "## dyno\n", _block(build_parser().format_help())]
        for name in COMMANDS:
            if not command_available(name):
                continue
            _, parser = command_parser(name)
            out += [f"## dyno {name}\n", _block(parser.format_help())]
            for sub in sub_parsers(parser):
                out += [f"### {sub.prog}\n", _block(sub.format_help())]
    finally:
        if before is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = before
    return "\n".join(out)


def _block(text: str) -> str:
    return "```text\n" + text.rstrip() + "\n```\n"


def main() -> int:
    sys.stdout.write(render())
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
