"""Where model solves run: one interface over this process, a local process pool and a Dask cluster.

``executor.map_unordered(fn, items)`` yields ``(index, result)`` as each item finishes.  ``fn`` must be a
module-level function and the items picklable (they cross process and machine boundaries).  Pick one with
:func:`make_executor`:

* ``jobs=1``: :class:`InlineExecutor`, in this process, one after another;
* ``jobs=N`` (default: the machine's cores): :class:`PoolExecutor`, ``concurrent.futures``' process pool;
* ``scheduler="tcp://HOST:8786"``: :class:`DaskExecutor`, a running ``dask.distributed`` scheduler and its
  workers on a lab's machines (the optional extra ``[cluster]``).  The caller keeps the results and the
  cache; workers need only ``dyno`` installed (no shared disk).

Why not a library that already does it all: ``concurrent.futures`` and ``distributed.Client`` are the two
libraries; this module is the twenty lines that let a study not care which one runs it.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed

from dyno.errors import ConfigError


class InlineExecutor:
    """In this process, in order."""

    name = "inline"

    def map_unordered(self, fn, items):
        for i, item in enumerate(items):
            yield i, fn(item)

    def close(self) -> None:
        pass


class PoolExecutor:
    """A local process pool of ``jobs`` workers."""

    def __init__(self, jobs: int) -> None:
        self.jobs = int(jobs)
        self.name = f"pool of {self.jobs}"
        self._pool = ProcessPoolExecutor(max_workers=self.jobs)

    def map_unordered(self, fn, items):
        futures = {self._pool.submit(fn, item): i for i, item in enumerate(items)}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        finally:  # interrupted (Ctrl+C, an error): what has not started never starts
            for fut in futures:
                fut.cancel()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor:
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

    def close(self) -> None:
        if self._own:
            self.client.close()


def make_executor(jobs: int | None = None, scheduler: str | None = None):
    """The executor the options ask for (see the module's docstring)."""
    if scheduler:
        return DaskExecutor(scheduler)
    n = int(jobs) if jobs else (os.cpu_count() or 1)
    return InlineExecutor() if n <= 1 else PoolExecutor(n)
