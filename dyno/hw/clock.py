"""Injectable time for the hardware layer: now in :mod:`dyno.clock` (below transports and hw).

Kept as a re-export so existing imports keep working.
"""

from dyno.clock import FakeClock, MonotonicClock

__all__ = ["FakeClock", "MonotonicClock"]
