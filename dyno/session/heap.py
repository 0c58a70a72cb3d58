"""Give the C heap's free pages back to the operating system between runs.

A process that runs test after test (the UI session's re-arms, a script calling ``dyno.session.root.run_test``)
frees each run's arrays, but glibc keeps freed pages in its per-thread arenas (each run starts its own
poller I/O and executor threads, which may land in a different arena): the resident size climbs for a
few hours until every arena has reached its high-water mark, though nothing is leaked — the 8-hour soak's
RSS rose 11 % this way, then stayed level (docs/safety.md, "Soak").  ``malloc_trim(0)`` hands those pages
back.  No library does this for us; it is one libc call, absent (and skipped) off glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        fn = libc.malloc_trim
    except (OSError, AttributeError):  # not glibc (musl, macOS): nothing to trim
        return None
    fn.argtypes, fn.restype = [ctypes.c_size_t], ctypes.c_int
    return fn


def return_free_heap() -> bool:
    """Release the C heap's free memory to the OS; True if any was released (False off glibc)."""
    fn = _malloc_trim()
    return bool(fn(0)) if fn is not None else False
