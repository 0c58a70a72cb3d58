"""The overlay's worker side: one point's solve (:func:`solve_job`), what travels between processes
(:class:`WarmState`), and the executors (:func:`process_pool`, :class:`InlineExecutor`).

Module-level functions only: a spawned worker process receives them by reference.
"""

from __future__ import annotations

import time
from concurrent.futures import Future

from dyno.model.params import ModelParams, OperatingPoint
from dyno.model.point_solve import WarmState, solve_strategy


class Cancelled(Exception):
    """The service was closed while this point was being solved."""


class InlineExecutor:
    """Runs each job at once in the caller's thread (a batch, a test)."""

    def submit(self, fn, *args, **kwargs) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001  (handed to the future, like a pool would)
            fut.set_exception(exc)
        return fut

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        pass


_WORKER_CANCEL = None  # a worker process's cancel event, from process_pool()'s initializer


def _init_worker(cancel) -> None:
    global _WORKER_CANCEL
    _WORKER_CANCEL = cancel
    import os

    # The parent may be a full-screen terminal UI on the same tty: nothing of the solver's may print there.
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)


def process_pool():
    """(executor, cancel event): a one-process pool for the service and the event its worker got at start.

    The solver then runs in its own interpreter: its numerics never hold the GIL of the process whose event
    loop polls the rig (in a thread, a solve can stall the control loop long enough to trip the watchdog).  Spawned, not forked: the parent has threads (Textual, the watchdog).
    """
    import multiprocessing
    import sys
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import resource_tracker

    ctx = multiprocessing.get_context("spawn")
    saved = sys.stderr
    try:
        # multiprocessing's helper process inherits sys.stderr's file descriptor: a UI that captured
        # sys.stderr (Textual) has none, so start it on the real one.
        if sys.__stderr__ is not None:
            sys.stderr = sys.__stderr__
        resource_tracker.ensure_running()
        cancel = ctx.Event()
    finally:
        sys.stderr = saved
    pool = ProcessPoolExecutor(1, mp_context=ctx, initializer=_init_worker, initargs=(cancel,))
    # Start the worker now, importing the solver there (the first point then pays neither), and without
    # re-running the parent's __main__ script in it (spawn would, for an unguarded script): only dyno's
    # module-level functions are ever sent to it.
    main = sys.modules.get("__main__")
    hide = main is not None and getattr(main, "__spec__", None) is None and hasattr(main, "__file__")
    saved_file = main.__file__ if hide else None
    try:
        if hide:
            del main.__file__
        pool.submit(_import_solver)
    finally:
        if hide:
            main.__file__ = saved_file
    return pool, cancel


def _import_solver() -> None:
    import dyno.model.solution  # noqa: F401  (imported for the first job)


def solve_job(params: ModelParams, op: OperatingPoint, *, variant: str, slip_threshold_m_s: float, tol: float,
              time_limit_s: float, guess: WarmState | None = None, cancel=None, fallback: WarmState | None = None):
    """Solve one point in this process (:func:`dyno.model.point_solve.solve_strategy`), stoppable by the
    service's ``cancel`` event: (result dict, WarmState or None)."""
    cancel = cancel if cancel is not None else _WORKER_CANCEL

    def log(_record) -> None:  # called after every continuation step: the place to stop a closed service
        if cancel is not None and cancel.is_set():
            raise Cancelled("overlay service closed")

    t0 = time.perf_counter()
    res, warm, start, steps = solve_strategy(params, op, guess=guess, fallback=fallback, variant=variant,
                                             slip_threshold_m_s=slip_threshold_m_s, tol=tol,
                                             time_limit_s=time_limit_s, log=log)
    res.update(ratio=op.ratio, primary_speed_rpm=op.primary_speed_rpm, primary_torque_nm=op.primary_torque_nm,
               variant=variant, start=start, steps=steps, job_s=time.perf_counter() - t0)
    return res, warm
