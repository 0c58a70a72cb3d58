"""Where model solves run: one interface over this process, a local process pool and a Dask cluster.

``executor.map_unordered(fn, items)`` yields ``(index, result)`` as each item finishes.  ``fn`` must be a
module-level function and the items picklable (they cross process and machine boundaries).  Pick one with
:func:`make_executor`:

* ``jobs=1``: :class:`InlineExecutor`, in this process, one after another;
* ``jobs=N`` (default: the machine's cores): :class:`PoolExecutor`, a ``multiprocessing`` pool;
* ``scheduler="tcp://HOST:8786"``: :class:`DaskExecutor`, a running ``dask.distributed`` scheduler and its
  workers on a lab's machines (the optional extra ``[cluster]``).  The caller keeps the results and the
  cache; workers need only ``dyno`` installed (no shared disk).

Why not a library that already does it all: ``multiprocessing`` and ``distributed.Client`` are the two
libraries; this module is the few lines that let a study not care which one runs it.
"""

from __future__ import annotations

import multiprocessing
import os
import signal

from dyno.errors import ConfigError


class _Executor:
    """``with executor:`` — on an exception (Ctrl+C included) the workers are stopped, not waited for."""

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(abort=exc_type is not None)

    def close(self, abort: bool = False) -> None:
        pass


class InlineExecutor(_Executor):
    """In this process, in order."""

    name = "inline"

    def map_unordered(self, fn, items):
        for i, item in enumerate(items):
            yield i, fn(item)


def _ignore_sigint() -> None:
    # Ctrl+C on a terminal reaches the whole process group: the parent decides (it stops the workers);
    # a worker that died of it mid-task would leave the pool waiting for it.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _indexed(args):
    fn, i, item = args
    return i, fn(item)


class PoolExecutor(_Executor):
    """A local pool of ``jobs`` worker processes (``multiprocessing.Pool``: it can be terminated)."""

    def __init__(self, jobs: int) -> None:
        self.jobs = int(jobs)
        self.name = f"pool of {self.jobs}"
        self._pool = multiprocessing.Pool(self.jobs, initializer=_ignore_sigint)

    def map_unordered(self, fn, items):
        yield from self._pool.imap_unordered(_indexed, [(fn, i, item) for i, item in enumerate(items)])

    def close(self, abort: bool = False) -> None:
        if abort:  # interrupted: what runs is stopped (its result was not stored; a resumed study solves it)
            self._pool.terminate()
        else:
            self._pool.close()
        self._pool.join()


class DaskExecutor(_Executor):
    """The workers of a ``dask.distributed`` scheduler (``address``) or of a ``Client`` given."""

    def __init__(self, address: str | None = None, *, client=None) -> None:
        try:
            from distributed import Client
        except ImportError:
            raise ConfigError("command line", "--scheduler",
                              "needs Dask: pip install 'dyno[cluster]' (dask.distributed)") from None
        self._own = client is None
        try:
            self.client = client if client is not None else Client(address, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise ConfigError("command line", "--scheduler",
                              f"a running dask scheduler at {address!r} ({type(exc).__name__}: {exc})") from None
        self.name = f"dask {self.client.scheduler.address}"

    def map_unordered(self, fn, items):
        from distributed import as_completed as dask_completed

        futures = self.client.map(fn, list(items), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in dask_completed(futures):
                yield index[fut.key], fut.result()
        finally:
            self.client.cancel(futures)

    def close(self, abort: bool = False) -> None:
        if self._own:
            self.client.close()


def make_executor(jobs: int | None = None, scheduler: str | None = None):
    """The executor the options ask for (see the module's docstring)."""
    if scheduler:
        return DaskExecutor(scheduler)
    n = int(jobs) if jobs else (os.cpu_count() or 1)
    return InlineExecutor() if n <= 1 else PoolExecutor(n)
