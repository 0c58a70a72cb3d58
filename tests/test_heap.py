"""dyno.session.heap: freed C-heap pages held by glibc go back to the OS (the soak's RSS growth, docs/safety.md)."""

import sys
from pathlib import Path

import pytest

from dyno.session.heap import return_free_heap

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise AssertionError("no VmRSS")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim and /proc: Linux only")
def test_freed_fragmented_heap_is_returned():
    # 60 MB in 2 kB blocks (malloc, not pymalloc), every 64th kept: the freed ones sit below live ones, so
    # the heap's top cannot shrink by itself and the pages stay resident until trimmed.
    blocks = [bytearray(2048) for _ in range(30_000)]
    for b in blocks:
        b[::512] = b"\x01" * 4  # touch the pages
    kept = blocks[::64]
    del blocks
    held_mb = _rss_mb()
    assert return_free_heap() is True
    assert _rss_mb() < held_mb - 30.0, (held_mb, _rss_mb())
    assert len(kept) == 469
