"""What happens to an ended run, whoever ran it (``dyno run``, ``dyno ui``, the UI's background re-arm, a test).

Library code: no printing.  Each failure is handed to ``warn`` as one line (the run is on disk; a missing
report or index entry never changes how the run ended); the caller decides where lines go.

- :func:`add_driven_loss`: every point also gets its efficiency with the driven-side loss the gauge does not
  see added back (a coast-down's ``driven_loss.json``, :func:`dyno.analysis.coastdown.driven_loss_keys`);
- :func:`index_run`: the run library's entry (docs/library.md);
- :func:`write_run_report`: ``report.html`` into the run directory;
- :func:`finish_run`: the last two, for a run directory the caller only knows by name.
"""

from __future__ import annotations

from pathlib import Path


def add_driven_loss(result: dict, driven_loss: dict | None, rig_path=None) -> None:
    """Add the driven-loss keys to every point of ``result`` (nothing without a loss); their intervals carry
    the run's systematic terms on the rig file's basis (:func:`dyno.analysis.systematic.run_basis`)."""
    if driven_loss is None:
        return
    from dyno.analysis.coastdown import driven_loss_keys
    from dyno.analysis.systematic import run_basis
    from dyno.rig.config import load_rig

    basis = run_basis(result.get("ambient"), load_rig(rig_path))
    for p in result["points"]:
        p.update(driven_loss_keys(p, driven_loss, basis))


def index_run(run_dir, warn) -> bool:
    """Add ``run_dir`` to the run library (``None``: whatever is new in the runs directory); never raises."""
    from dyno.library.index import index_after_run

    return index_after_run(run_dir, warn)


def write_run_report(run_dir, warn) -> Path | None:
    """``report.html`` into ``run_dir``, or None after one line to ``warn`` saying why not."""
    try:
        if not run_dir or not Path(run_dir, "meta.json").is_file():
            raise FileNotFoundError(f"no run directory at {run_dir}")
        from dyno.report.writer import write_report

        return write_report(run_dir)
    except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001  the test is on disk; its report is extra
        why = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"{type(exc).__name__}: {exc}"
        warn(f"{run_dir}: report.html not written: {why} (`dyno report RUN` retries)")
        return None


def finish_run(run_dir, *, warn_index, warn_report, only_if_missing: bool = False,
               report: bool = True) -> tuple[bool, Path | None]:
    """Index an ended run and write its report.html; returns (a run was there, the report's path or None).

    ``only_if_missing``: keep a report already written (the UI's background one of a re-armed-from run)."""
    if run_dir is None or not (Path(run_dir) / "meta.json").is_file():
        return False, None  # the session never started a run there
    index_run(run_dir, warn_index)
    path = None
    if report and not (only_if_missing and (Path(run_dir) / "report.html").is_file()):
        path = write_run_report(str(run_dir), warn_report)
    return True, path


def _background_main(argv) -> None:
    """The UI's low-priority child process for a re-armed-from run (``python -c``, :mod:`dyno.ui.run_dirs`)."""
    finish_run(argv[1], warn_index=lambda line: None, warn_report=lambda line: None)
