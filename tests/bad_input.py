"""Shared checks of the house rule for bad input: one line naming the file/field, exit 2, nothing written."""

from __future__ import annotations

import hashlib
from pathlib import Path


def snapshot(root: Path) -> dict:
    """Every path under ``root`` with its content hash ("dir" for a directory): equal before and after = untouched."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(root.rglob("*"))}


def one_line_failures(cases, run) -> list[str]:
    """``cases``: (name, argv, what stderr must name: a string or several); ``run(*argv)`` -> CompletedProcess.
    Returns one message per case that did not exit 2 with one line of stderr naming everything asked."""
    failures = []
    for name, argv, names in cases:
        r = run(*argv)
        err = r.stderr.strip()
        problems = []
        if r.returncode != 2:
            problems.append(f"exit {r.returncode}")
        if "Traceback" in r.stderr or len(err.splitlines()) != 1:
            problems.append(f"stderr is not one line: {err[-600:]!r}")
        problems += [f"does not name {n!r}: {err[-300:]!r}" for n in ([names] if isinstance(names, str) else names)
                     if n not in err]
        if problems:
            failures.append(f"{name}: {'; '.join(problems)}")
    return failures
