"""What happens to an ended run, whoever ran it (``dyno run``, ``dyno ui``, the UI's background re-arm, a test).

Library code: no printing.  Each failure is handed to ``warn`` as one line (the run is on disk; a missing
report or index entry never changes how the run ended); the caller decides where lines go.

- :func:`end_test`: on the rig, once the test has ended: the brake's release stroke serviced to its end and, after
  a completed test, the torque zero read at rest (the ``torque_zero`` record, and the input channel's);
- :func:`close_run`: the air after the run, the run's summary and its ``safety`` document, the log closed;
- :func:`add_driven_loss`: every point also gets its efficiency with the driven-side loss the gauge does not
  see added back (a coast-down's ``driven_loss.json``, :func:`dyno.analysis.coastdown.driven_loss_keys`);
- :func:`index_run`: the run library's entry (docs/library.md);
- :func:`write_run_report`: ``report.html`` into the run directory;
- :func:`finish_run`: the last two, for a run directory the caller only knows by name.
"""

from __future__ import annotations

import asyncio
from pathlib import Path


async def end_test(ctx, *, finish_release: bool = True, poll_s: float = 0.1, pads_only: bool = False) -> None:
    """What follows a test's end while the rig is still polled: the release stroke serviced to its end
    (``finish_release``; ``pads_only``: until the pads are off, :func:`dyno.session.safe_outputs.finish_release`)
    and, after a completed test, the torque zero at rest beside it (:func:`dyno.control.zero_check.after_test`:
    the ``torque_zero`` record and, with an engine-side input channel, ``torque_zero_input``)."""
    from dyno.session.safe_outputs import finish_release as release

    zero_task = None
    if finish_release and ctx.controller.state.value == "done":  # the zero at rest after the last point
        from dyno.control.zero_check import after_test

        zero_task = asyncio.create_task(after_test(ctx.controller), name="torque-zero")
    try:
        await flush_commands(ctx)
        if finish_release:
            await release(ctx, poll_s=poll_s, pads_only=pads_only)
        if zero_task is not None:
            await zero_task
    finally:
        if zero_task is not None and not zero_task.done():  # (cancelled: a quit or a hang-up meanwhile)
            zero_task.cancel()


async def flush_commands(ctx, *, max_s: float = 1.0, step_s: float = 0.01) -> bool:
    """Keep the rig polled until the Nano has the commands the test left pending (the kill probe's latched
    cut of the run-enable goes with the next poll: a test that ends at once must not stop the polls first);
    True when none is left within ``max_s`` (loop seconds)."""
    reader = getattr(ctx.poller, "reader", None)
    loop = asyncio.get_running_loop()
    end = loop.time() + max_s
    while getattr(reader, "commands_pending", False):
        if loop.time() >= end:
            return False
        await asyncio.sleep(step_s)
    return True


def close_run(ctx, status: str | None = None, *, drills_from: int = 0) -> dict:
    """Close an ended run's log: the air after the run (a BME280 read again), the summary ``dyno run --json``
    prints (returned) and its ``safety`` document, then the end record with the link's figures.

    ``status``: the end record's (default: "success" after DONE, else "abort"); ``drills_from``: the first drill
    of ``ctx.drills.fired`` that is this run's (a UI session's re-armed runs share one drill runner).  A summary
    that cannot be made leaves a ``safety`` document saying why, the log closed, and is raised."""
    from dyno.session.ambient import log_end
    from dyno.session.summary import safety_document, summarize, supervisor_document

    writer = ctx.writer
    try:
        log_end(ctx)
        result = summarize(ctx, drills_from=drills_from)
        if writer.error is None:
            writer.doc("safety", **safety_document(result))
    except Exception as exc:
        if writer.error is None:
            writer.doc("safety", error=f"{type(exc).__name__}: {exc}")
        raise
    finally:
        if status is None:
            status = "success" if ctx.controller.state.value == "done" else "abort"
        writer.close(status, ctx.controller.reason, link=ctx.poller.link_health(),
                     events_lost=ctx.poller.reader.events_lost, supervisor=supervisor_document(ctx.poller.reader))
    return result


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

    ``only_if_missing``: keep a report already written (the UI's, written in the background when its test ended)."""
    if run_dir is None or not (Path(run_dir) / "meta.json").is_file():
        return False, None  # the session never started a run there
    index_run(run_dir, warn_index)
    path = None
    kept = Path(run_dir) / "report.html"
    if report and only_if_missing and kept.is_file():
        path = kept
    elif report:
        path = write_run_report(str(run_dir), warn_report)
    return True, path


def _background_main(argv) -> None:
    """The UI's low-priority child process for a re-armed-from run (``python -c``, :mod:`dyno.ui.run_dirs`)."""
    finish_run(argv[1], warn_index=lambda line: None, warn_report=lambda line: None)
