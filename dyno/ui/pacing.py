"""Pacing a simulated rig on the UI's real-time loop: lives in :mod:`dyno.session.pacing` (the composition root paces
the run from the session's scaled clock); re-exported here for the UI's modules and tests."""

from dyno.session.pacing import ScaledClock, SimTimeActuators  # noqa: F401
