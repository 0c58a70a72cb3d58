"""An unknown start is not a release (issue 49, item 3): the Pi's output code on the wiring twin over the
simulated physics (K3 fitted), started with the brake at 0, mid-travel or full apply and the end switch
working, stuck closed or stuck open.

The controller's start is played as it runs (:func:`dyno.control.outputs.ignition_hold_ended`): a safe state,
then the ignition enabled as soon as the driver stops holding the chain open, then a first brake apply.  The
verdicts are the physics': when the pads first left the rotor, when the kill chain first closed, where the
actuator truly is.
"""

from __future__ import annotations

import dataclasses

import pytest

from dyno.control.outputs import APPLY
from dyno.errors import SafetyAbort
from dyno.clock import FakeClock
from dyno.hw.mockpins import SimPinFactory
from dyno.hw.outputs import GpioActuators
from dyno.rig.config import load_rig
from dyno.sim.physics import RigModel
from dyno.sim.rig import SimActuators
from dyno.sim.rig_params import RigParams

pytestmark = pytest.mark.quick

DT_S = 0.02  # the control loop's beat, about (well inside the Nano's 0.2 s heartbeat: no gap)
STARTS_MM = (0.0, 20.0, 40.0)  # released, mid-travel (pads on), full apply
SWITCHES = (None, "stuck_closed", "stuck_open")


def _rig():
    cfg = load_rig(None)
    pins = dataclasses.replace(cfg.pins, brake_released_input=27, estop_input=22)
    assert cfg.actuator.brake_hold_relay  # K3 fitted, as shipped
    return dataclasses.replace(cfg, pins=pins)


def _start(start_mm: float, switch: str | None, apply_s: float = 0.5):
    """Play a run's start; returns (model, driver, ignition refused while held?, fault names)."""
    cfg = _rig()
    clock = FakeClock(start_s=0.0)
    model = RigModel(RigParams(brake_start_mm=start_mm), seed=3)
    model.brake_hold_relay = True
    model.engine_enabled = False  # the Pi's outputs from power-up (dyno.session.root)
    sim_act = SimActuators(model, full_stroke_s=cfg.actuator.full_stroke_s,
                           sync=lambda: model.step(max(0.0, clock.now() - model.t_s)))
    twin = SimPinFactory(cfg, sim_act, clock, seed=0)
    twin.end_switch_mode = switch  # the switch as it is from power-up
    act = GpioActuators(cfg, pin_factory=twin, clock=clock)
    twin.arm()

    def beat() -> None:
        clock.advance(DT_S)
        model.step(max(0.0, clock.now() - model.t_s))
        act.tick(clock.now())

    act.safe_state()  # the start of a run
    beat()
    refused_early = False
    try:
        act.engine_kill(False)
    except SafetyAbort:
        refused_early = True
    while act.ignition_held:
        beat()
        assert clock.now() < 3 * cfg.actuator.full_stroke_s, "the ignition hold never ended"
    act.engine_kill(False)
    beat()
    act.brake_step(APPLY, apply_s)  # the first apply that follows
    for _ in range(round((apply_s + 0.3) / DT_S)):
        beat()
    return model, act, refused_early


@pytest.mark.parametrize("switch", SWITCHES)
@pytest.mark.parametrize("start_mm", STARTS_MM)
def test_the_chain_closes_only_after_the_full_stroke_and_never_before_the_pads_are_off(start_mm, switch):
    model, act, refused_early = _start(start_mm, switch)
    stroke_s = act.brake_full_stroke_s
    assert refused_early  # engine_kill(False) at once is refused: the position is not known
    on_s = model.ignition_enabled_at_s
    off_s = model.startup_released_at_s
    assert off_s is not None and on_s is not None
    assert on_s >= off_s  # the physics: the pads were off the rotor before the chain first closed
    if start_mm <= model.brake.a0_mm:
        assert off_s == 0.0
    # a closed switch never shortens it: the full stroke (+ the overrun) ran before the chain closed
    assert on_s >= 1.0 * stroke_s
    faults = [f for f in act.faults if f["channel"] == "end_switch"]
    if switch is None:
        assert faults == []
        assert model.actuator_mm > model.brake.a0_mm  # the first apply moved the brake onto the rotor
    else:
        assert len(faults) == 1, faults
        said = faults[0]["detail"]
        assert ("stuck closed" in said) if switch == "stuck_closed" else ("stuck open" in said)
        assert act.fault_refusal() and "end-of-travel switch" in act.fault_refusal()


def test_the_stuck_closed_switch_is_named_within_the_stated_travel_of_the_first_apply():
    """The switch must open within ``tolerance`` of the stroke from the stop (dyno.hw.endswitch): ABS_TOL / (1 -
    REL_TOL) = 1.6 % of the stroke (0.6 mm of 40 mm); judged at the beats, so within one beat more."""
    from dyno.hw.endswitch import ABS_TOL, REL_TOL

    model, act, _ = _start(20.0, "stuck_closed", apply_s=0.5)
    f = next(f for f in act.faults if f["channel"] == "end_switch")
    stated_s = ABS_TOL / (1.0 - REL_TOL) * act.brake_full_stroke_s
    on_s = model.ignition_enabled_at_s
    # the apply began about a relay settle or two after the chain closed; the fault a beat after the stated travel
    assert f["t_s"] - on_s <= stated_s + 2 * act.config.actuator.relay_settle_s + 3 * DT_S


def test_after_the_fault_every_release_runs_the_full_stroke():
    model, act, _ = _start(20.0, "stuck_closed", apply_s=0.5)
    clock = act.clock
    act.safe_state(latch=True)
    t0 = clock.now()
    while not act.release_confirmed:
        clock.advance(DT_S)
        model.step(max(0.0, clock.now() - model.t_s))
        act.tick(clock.now())
        assert clock.now() - t0 < 3 * act.brake_full_stroke_s
    assert act.release_basis == "full_stroke_time"
    assert clock.now() - t0 >= act.brake_full_stroke_s  # not cut short by the (stuck) closed switch
    assert model.pads_off
