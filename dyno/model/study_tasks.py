"""Model studies as independent tasks: cached by their inputs and the model's code, resumable, run anywhere.

A task is one continuation walk (:func:`dyno.model.sweep.sweep_ratios`) over some ratios of one parameter
set: a study's value, or one side of an operating-range sweep walked outwards from its first point.  Its
result (the rows) is stored under ``<cache>/studies/<key>.json`` the moment it arrives, keyed by
everything that decides it — the parameters, the operating point, the ratios, variant, slip threshold,
tolerance and :func:`dyno.model.cache_keys.model_code_hash` — so an interrupted study, run again, solves only
what is missing, and a changed model invalidates the lot.  The warm start a task is handed (a solution
near its first ratio) is not in the key: it speeds the walk, it does not choose the answer.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from dyno.errors import MODEL_FAILURES
from dyno.model.params import ModelParams, OperatingPoint


@dataclass(frozen=True)
class SweepTask:
    label: str  # what the task is in the study (e.g. "friction=0.4")
    params: ModelParams
    op: OperatingPoint
    ratios: tuple
    variant: str = "corrected"
    slip_threshold_m_s: float = 1e-4
    tol: float = 1e-3
    guess: object = None  # a solution to reach this task's own start from by homotopy (not in the key)
    homotopy: bool = False  # True: solve op at ratio 1 from ``guess`` first (a study's value from its baseline)


def task_key(task: SweepTask) -> str:
    from dyno.model.cache_keys import model_code_hash

    payload = {"code": model_code_hash(), "params": task.params.as_dict(), "op": asdict(task.op),
               "ratios": [round(float(r), 12) for r in task.ratios], "variant": task.variant,
               "slip": task.slip_threshold_m_s, "tol": task.tol, "homotopy": task.homotopy}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=float).encode()).hexdigest()[:32]


def run_task(task: SweepTask) -> list[dict]:
    """Solve one task (in whichever process or machine the executor chose): its rows, in ratio order given."""
    from dyno.model import sweep
    from dyno.model.solution import solve_point

    start = task.guess
    if task.homotopy and task.guess is not None:
        try:
            start = solve_point(task.params, replace(task.op, ratio=1.0), variant=task.variant,
                                slip_threshold_m_s=task.slip_threshold_m_s, tol=task.tol, guess=task.guess)
        except MODEL_FAILURES:
            start = None  # from its own geometric guess
    rows, _ = sweep.sweep_ratios(task.ratios, task.params, task.op, variant=task.variant,
                                 slip_threshold_m_s=task.slip_threshold_m_s, tol=task.tol, start=start)
    return rows


def study_cache_dir(cache_dir=None) -> Path:
    from dyno.model.cache_keys import default_cache_dir

    return Path(cache_dir) / "studies" if cache_dir is not None else default_cache_dir() / "studies"


def run_tasks(tasks, executor, *, cache_dir=None, use_cache: bool = True, progress=None) -> tuple[list, dict]:
    """Every task's rows (in task order) and ``{"computed": n, "cached": n}``.

    Cached results are read first; the rest go to ``executor`` and each is stored as it arrives, so an
    interruption (Ctrl+C, a lost worker) loses only the tasks still running.  ``progress(done, total,
    label, cached)`` after each one.
    """
    tasks = list(tasks)
    cache = study_cache_dir(cache_dir)
    out: list = [None] * len(tasks)
    keys = [task_key(t) for t in tasks]
    todo = []
    for i, (t, key) in enumerate(zip(tasks, keys)):
        path = cache / f"{key}.json"
        if use_cache and path.is_file():
            try:
                out[i] = json.loads(path.read_text())["rows"]
            except (OSError, ValueError, KeyError):
                out[i] = None  # unreadable entry: solve again, overwrite
        if out[i] is None:
            todo.append(i)
    counts = {"computed": 0, "cached": len(tasks) - len(todo)}
    done = counts["cached"]
    if progress:
        for i in range(len(tasks)):
            if i not in todo:
                progress(done, len(tasks), tasks[i].label, True)
    for j, rows in executor.map_unordered(run_task, [tasks[i] for i in todo]):
        i = todo[j]
        out[i] = rows
        counts["computed"] += 1
        done += 1
        if use_cache:
            _store(cache, keys[i], tasks[i], rows)
        if progress:
            progress(done, len(tasks), tasks[i].label, False)
    return out, counts


def _store(cache: Path, key: str, task: SweepTask, rows: list) -> None:
    try:
        cache.mkdir(parents=True, exist_ok=True)
        tmp = cache / f"{key}.json.{os.getpid()}.tmp"
        tmp.write_text(json.dumps({"label": task.label, "rows": rows}, default=float))
        tmp.replace(cache / f"{key}.json")  # atomic: an interrupted write leaves no half entry
    except OSError:
        pass  # a read-only cache must not stop the study
