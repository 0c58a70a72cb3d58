"""Shared hardware-test fixtures: one mock pin factory that records every pin change."""

from __future__ import annotations

import dataclasses

import pytest
from gpiozero import Device

from dyno.clock import FakeClock
from dyno.hw.testing import RecordingFactory
from dyno.rig.config import load_rig


@pytest.fixture
def clock():
    return FakeClock()


@pytest.fixture
def rig():
    cfg = load_rig()
    # Shorter stroke keeps FakeClock loops short; relay settle stays realistic.  A bare MockFactory wires no
    # E-stop contact or end switch behind the shipped rig's inputs: the tests that need them declare them on a
    # twin or a chain pin of their own (rig_wired, rig_estop).
    pins = dataclasses.replace(cfg.pins, estop_input=None, brake_released_input=None)
    return dataclasses.replace(cfg, pins=pins, actuator=dataclasses.replace(cfg.actuator, full_stroke_s=2.0))


@pytest.fixture
def factory(clock):
    """gpiozero 2 keeps a global Device.pin_factory: set it, and always restore it."""
    saved = Device.pin_factory
    f = RecordingFactory(clock)
    Device.pin_factory = f
    try:
        yield f
    finally:
        f.reset()
        Device.pin_factory = saved


@pytest.fixture
def actuators(rig, factory, clock):
    from dyno.hw.outputs import GpioActuators

    act = GpioActuators(rig, pin_factory=factory, clock=clock)
    yield act
    act.close()


