"""Shared helpers for the simulator tests: drive a RigModel like the host does."""

from __future__ import annotations

import numpy as np
import pytest

from dyno.sim.physics import RigModel
from dyno.sim.rig_params import RigParams

HOST_DT_S = 1.0 / 150.0   # the host polls at 150 Hz; the device steps the physics at that pace


class Driver:
    """Steps a model at the host's pace, collecting events and truth samples."""

    def __init__(self, model: RigModel, dt_s: float = HOST_DT_S):
        self.model = model
        self.dt_s = dt_s

    def run(self, duration_s: float):
        """Advance ``duration_s``; return (events, truths sampled after each step)."""
        events, truths = [], []
        for _ in range(int(round(duration_s / self.dt_s))):
            events.extend(self.model.step(self.dt_s))
            truths.append(self.model.truth())
        return events, truths

    def start_full_throttle(self, settle_s: float = 6.0):
        self.model.start_engine()
        self.run(2.0)
        self.model.throttle_frac = 1.0
        return self.run(settle_s)

    def brake_step(self, on_s: float, settle_s: float):
        self.model.actuator_dir = 1
        self.run(on_s)
        self.model.actuator_dir = 0
        return self.run(settle_s)


def _mean_truth(truths, name):
    return float(np.mean([getattr(t, name) for t in truths]))


@pytest.fixture
def make_driver():
    def _make(seed: int = 0, **overrides) -> Driver:
        # the thesis rig as specified (its engine exactly its map, the reference day) unless a test says
        # otherwise: these check the signal chain and the drivetrain at that rig's operating points; a
        # seed's own engine, sensor and day (dyno.sim.world) are tests/sim/test_sim_world.py's
        overrides.setdefault("ideal", True)
        return Driver(RigModel(RigParams(**overrides), seed=seed))
    return _make
