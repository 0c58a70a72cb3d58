"""Every abort path ends in the safe state within 100 ms (simulated) and the log says why."""

import asyncio
from dataclasses import replace

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.control.safety import SafetyLimits
from dyno.runlog.reader import load_run

from .conftest import QUICK_PLAN

SAFE_WITHIN_S = 0.100


def _run_with(tmp_path, name, setup=None, limits=None):
    captured = {}

    def _setup(ctx):
        captured["ctx"] = ctx
        if setup:
            setup(ctx)

    result = run_test(RunSpec(sim=True, seed=3, out_dir=tmp_path / name, plan=QUICK_PLAN, setup=_setup,
                                 limits=limits))
    return result, captured["ctx"]


def _assert_safe(result, ctx, cause):
    assert result["state"] == "aborted"
    aborts = result["aborts"]
    assert [a["cause"] for a in aborts] == [cause]
    a = aborts[0]
    # when the outputs (the physics' inputs) received the safe state, in the simulated world's time, against
    # when the condition became true (the controller's clock is the same virtual time)
    act = ctx.sim.actuators
    safe_times = [t for t, what, _ in act.history if what == "safe_state" and t >= a["trigger_s"] - 1e-9]
    assert safe_times and safe_times[0] - a["trigger_s"] <= SAFE_WITHIN_S + 0.004  # physics grid: 4 ms
    m = ctx.sim.model
    # and the state the physics ended in: throttle idle, ignition off, pads off the rotor, actuator off
    assert m.throttle_frac == 0.0 and not m.engine_enabled and m.actuator_dir == 0
    assert m.actuator_mm <= m.brake.a0_mm and result["rig_safe"] is True
    run = load_run(result["run_dir"])
    logged = run.docs("abort")
    assert logged and logged[0]["cause"] == cause and logged[0]["detail"]
    assert run.stop["exit_status"] == "abort"


def test_over_temperature_aborts_to_safe_state(tmp_path):
    result, ctx = _run_with(tmp_path, "hot", limits=SafetyLimits(rotor_temp_max_c=90.0))
    _assert_safe(result, ctx, "over_temperature")
    assert ctx.sim.model.rotor_temp_c > 85.0


def test_lost_bus_aborts_to_safe_state(tmp_path):
    def setup(ctx):
        def cut():
            ctx.sim.bus.faults.nack_rate = 1.0  # the cable falls out

        asyncio.get_running_loop().call_later(40.0, cut)

    result, ctx = _run_with(tmp_path, "lost", setup)
    _assert_safe(result, ctx, "comms_lost")
    assert result["aborts"][0]["trigger_s"] == pytest.approx(40.25, abs=0.02)  # rig.toml comms_timeout_s


def test_estop_aborts_to_safe_state(tmp_path):
    def setup(ctx):
        asyncio.get_running_loop().call_later(35.0, ctx.controller.estop, "test")

    result, ctx = _run_with(tmp_path, "estop", setup)
    _assert_safe(result, ctx, "estop")


def test_engine_stops_after_an_abort(tmp_path):
    """Safe means safe: after the E-stop the engine spins down and the brake retracts."""
    def setup(ctx):
        loop = asyncio.get_running_loop()
        loop.call_later(35.0, ctx.controller.estop, "test")

    result, ctx = _run_with(tmp_path, "spin", setup)
    m = ctx.sim.model
    t_abort = result["aborts"][0]["trigger_s"]
    act_before = m.actuator_mm
    m.step(10.0)  # ten more seconds of physics after the run ended
    truth = m.truth()
    assert truth.rpm_primary < 100 and not truth.engine_running
    assert act_before == 0.0  # the release stroke completed before the run closed
    assert t_abort == pytest.approx(35.0, abs=0.01)
