"""The next run on the same rig (a re-arm in ``dyno ui``): its log and its controller, built here, beside the
composition root (:mod:`dyno.session.root`) that built the first, from the same parts.

A long-lived session keeps the poller, the rig, its safety and its watchdog; each run gets a new
:class:`~dyno.runlog.writer.RunWriter` and a new :class:`~dyno.control.controller.TestController`, given what the
root gave the first one (:data:`REBUILT_ATTRS`), never patched after construction.  Two steps, so that a log that
cannot be written changes nothing: :func:`open_next_log` first, then :func:`start_next_controller`.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

# What the root gives a controller's constructor beside the plan and its parts (rig.toml's description, control
# gains and inertias, the tune, the input channel as tared, the paced session's clock): a re-armed controller is
# given the same.  (Without ``clock`` a re-armed x4 session would time its plan in host seconds.)
REBUILT_ATTRS = ("rig", "tune_path", "shift_prediction", "control", "inertia", "clock", "input_channel")
#: inputs a run keeps beside its log that the next run keeps too
INPUT_COPIES = ("plan.toml",)


def abort_on_write_error(controller_of: Callable[[], object], run_dir) -> Callable[[BaseException], None]:
    """The writer's ``on_error``, given to its constructor: a log that cannot be written aborts the test
    (``controller_of()``: the controller built after the writer, it is given the writer) into the safe state.  A
    write that fails before the controller exists (the writer's own ``start`` record) is kept in the writer's
    ``error``, as it always was."""
    def on_error(exc) -> None:
        controller = controller_of()
        if controller is None:
            return
        controller.abort("disk_full", f"cannot write the run log ({getattr(exc, 'strerror', None) or exc}: "
                         f"{getattr(exc, 'filename', '') or run_dir}): safe state; what was recorded before stays "
                         "readable")
    return on_error


@dataclass
class NextLog:
    """The next run's open log and the engine map taken to its day."""
    writer: object
    engine_map: object
    meta: dict
    run_dir: Path


def open_next_log(ctx, old_dir: Path, new_dir: Path) -> NextLog:
    """The next run's log in ``new_dir``: the ended run's metadata (less what is per run), its calibration, map,
    tune and plan, and the day's air read again when the rig has a sensor.  Raises ``DynoError``, ``OSError`` or
    ``ValueError`` before anything of the session has changed."""
    from dyno.runlog.writer import RunWriter

    old = ctx.controller
    meta = json.loads((old_dir / "meta.json").read_text())
    for k in ("software_version", "created_unix_s", "format"):
        meta.pop(k, None)
    meta["rearmed_after"] = str(old_dir)
    engine_map = old.engine_map
    if ctx.ambient_sensor is not None:  # each run its own air, read when it is armed
        from dyno.hw.bme280 import read_sensor

        amb = read_sensor(ctx.ambient_sensor, "BME280")
        engine_map = engine_map.at_ambient(amb.temp_c, amb.dry_pressure_kpa)
        meta["ambient"] = amb.to_dict()
    tune = old_dir / "tune.toml"

    def writing_controller():  # the session's controller once it writes this log (start_next_controller)
        return ctx.controller if ctx.controller.writer is writer else None

    writer = RunWriter(new_dir, meta, calibration=old.calibration.to_dict(),
                       engine_map_text=(old_dir / "engine_map.csv").read_text(),
                       tune_text=tune.read_text() if tune.is_file() else None,
                       on_error=abort_on_write_error(writing_controller, new_dir))
    for name in INPUT_COPIES:
        if (old_dir / name).is_file() and not (new_dir / name).exists():
            shutil.copy2(old_dir / name, new_dir / name)
    return NextLog(writer, engine_map, meta, new_dir)


def start_next_controller(ctx, log: NextLog, *, loop, stop_watchdog, listeners=()):
    """Hand the poller from the ended run to the next: the old log and controller stop listening, the new ones
    start, the watchdog beats for the new controller.  Returns (the new controller, not started: the caller's
    loop runs it; the watchdog's stop callable).  ``listeners``: the face's controller listeners, given at
    construction; ``stop_watchdog``: what :func:`dyno.session.safety.start_watchdog` returned."""
    from dyno.control.controller import TestController
    from dyno.session.safety import next_watchdog, rehook_watchdog, uncuttable_warning, watchdog_beat

    old, poller = ctx.controller, ctx.poller
    poller.listeners.remove(ctx.writer.events)
    old.detach()  # an ended controller checks nothing, but costs a call per poll
    wd = next_watchdog(ctx, loop)
    ctrl = TestController(poller, old.act, old.calibration, log.engine_map, plan=old.plan, limits=old.limits,
                          writer=log.writer, auto_go=False, on_wait_engine=old.on_wait_engine,
                          runner_for=old.runner_for, from_idle=old.from_idle,
                          **{name: getattr(old, name) for name in REBUILT_ATTRS},
                          point_hooks=old.point_hooks,  # (the simulated rig's truth: keyed by time, not by run)
                          result_hooks=old.result_hooks, listeners=(uncuttable_warning(), *listeners),
                          # (the beat aborts through the controller it beats for: called once it runs)
                          heartbeat_hooks=(watchdog_beat(wd, lambda: ctrl, ctx.rig_cfg.actuator.watchdog_s),))
    poller.listeners.append(log.writer.events)
    ctx.ambient = dict(log.meta.get("ambient") or {})
    ctx.writer, ctx.controller = log.writer, ctrl
    return ctrl, rehook_watchdog(ctx, wd, loop, stop_watchdog)
