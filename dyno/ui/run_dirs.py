"""Where a re-armed UI session's next run goes, and finishing an ended run in the background."""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path


def next_run_dir(old: Path, out_dir: Path | None) -> Path:
    """The next run's directory: ``<--out>-2``, ``-3``, ... beside the one given, else a new runs/<timestamp>."""
    if out_dir is None:
        from dyno.session.root import default_run_dir

        return default_run_dir(old.parent)
    base = Path(out_dir)
    n = 2
    while (base.parent / f"{base.name}-{n}").exists():
        n += 1
    return base.parent / f"{base.name}-{n}"


async def finish_in_background(run_dir: Path) -> None:
    """report.html and the run library's entry for an ended run, in a low-priority child process
    (matplotlib would hold the loop, and the GIL, for seconds)."""
    code = "import os, sys; os.nice(10); from dyno.session.after import _background_main; _background_main(sys.argv)"
    try:
        proc = await asyncio.create_subprocess_exec(sys.executable, "-c", code, str(run_dir),
                                                    stdin=asyncio.subprocess.DEVNULL,
                                                    stdout=asyncio.subprocess.DEVNULL,
                                                    stderr=asyncio.subprocess.DEVNULL)
        await proc.wait()
    except (OSError, asyncio.CancelledError):
        pass  # `dyno ui` retries at exit (report.html missing), `dyno report RUN` any time
