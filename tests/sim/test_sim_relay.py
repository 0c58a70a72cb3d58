"""The brake actuator's direction relay in the physics: unpowered while its contacts transfer."""

from __future__ import annotations

import pytest

from dyno.clock import FakeClock
from dyno.control.outputs import APPLY, RELEASE, STOP
from dyno.hw.mockpins import mock_pin_actuators
from dyno.rig.config import load_rig
from dyno.sim.physics import RigModel
from dyno.sim.rig_params import RigParams
from dyno.sim.rig import SimActuators

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

CELL_S = RigParams().max_substep_s  # inputs act from the next physics cell: one cell of slack
MM_PER_S = RigParams().actuator_speed_mm_s
TRANSFER_S = RigParams().relay_transfer_s


def _pulse(model: RigModel, direction: int, on_s: float, rest_s: float = 0.1) -> float:
    """Power the actuator for ``on_s`` then stop; returns how far it moved (mm)."""
    before = model.actuator_mm
    model.actuator_dir = direction
    model.step(on_s)
    model.actuator_dir = STOP
    model.step(rest_s)
    return model.actuator_mm - before


def test_a_reversal_pulse_shorter_than_the_relay_transfer_moves_nothing():
    m = RigModel(seed=1)
    assert TRANSFER_S == pytest.approx(0.015)
    tol = MM_PER_S * CELL_S
    assert _pulse(m, APPLY, 0.012) == pytest.approx(0.0, abs=1e-12)  # relay at rest (release): in transit
    # the coil stays on APPLY after the stop: the next apply moves for its whole length
    assert _pulse(m, APPLY, 0.040) == pytest.approx(MM_PER_S * 0.040, abs=tol)
    # a reversal loses the transfer time, a same-side pulse nothing
    pos = m.actuator_mm
    assert _pulse(m, RELEASE, 0.040) == pytest.approx(-MM_PER_S * (0.040 - TRANSFER_S), abs=tol)
    assert m.actuator_mm < pos
    assert _pulse(m, RELEASE, 0.008) == pytest.approx(-MM_PER_S * 0.008, abs=tol)


def test_the_real_driver_settles_the_relay_before_the_enable_so_no_motion_is_lost_twice():
    """Through GpioActuators on mock pins the relay pin changes with the enable off and the driver waits
    rig.toml's relay_settle_s (30 ms) before powering: the contacts (15 ms) have made by then, so the
    motion is the powered time; the bare simulated actuators lose only the transfer itself."""
    cfg = load_rig(None)
    assert cfg.actuator.relay_settle_s >= TRANSFER_S  # the driver's wait covers the relay's
    dt = 0.001

    def run_apply(actuators, model, clock, on_s):
        # a driver starts with a release of the full stroke (the position is unknown), no apply before it ends
        actuators.safe_state()
        for _ in range(200):
            clock.advance(0.05)
            model.step(0.05)
            actuators.tick(clock.now())
        start_mm = model.actuator_mm
        actuators.brake(APPLY)
        for _ in range(round(on_s / dt)):
            clock.advance(dt)
            model.step(dt)
            actuators.tick(clock.now())
        actuators.brake(STOP)
        model.step(0.05)
        return model.actuator_mm - start_mm

    m_drv, clock = RigModel(seed=2), FakeClock()
    drv, _ = mock_pin_actuators(cfg, SimActuators(m_drv), clock)
    moved_drv = run_apply(drv, m_drv, clock, 0.2)
    m_bare = RigModel(seed=2)
    moved_bare = run_apply(SimActuators(m_bare), m_bare, FakeClock(), 0.2)
    tol = MM_PER_S * (CELL_S + dt)
    assert moved_drv == pytest.approx(MM_PER_S * (0.2 - cfg.actuator.relay_settle_s), abs=tol)
    assert moved_bare == pytest.approx(MM_PER_S * (0.2 - TRANSFER_S), abs=tol)
