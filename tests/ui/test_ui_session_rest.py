"""A live session after its test has ended: the polls service the safe state's release stroke to its end (the
test's heartbeat stopped with the test), and once the rig is at rest the poller drops to the idle rate."""

from __future__ import annotations

import asyncio
import time

import pytest

from dyno.control.api import State
from dyno.control.outputs import STOP
from dyno.ui.session import LiveOptions, LiveSession


async def _until(cond, timeout_s: float) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if cond():
            return True
        await asyncio.sleep(0.05)
    return cond()


def test_after_an_estop_the_release_stroke_ends_and_the_rig_at_rest_polls_at_the_idle_rate(tmp_path):
    async def scenario():
        s = LiveSession(LiveOptions(sim=True, speed=8.0, seed=2, out_dir=tmp_path / "run"))
        s.start()
        try:
            assert await _until(lambda: s.controller.state is State.ARMED, 30), s.controller.reason
            idle_period_s = 1 / s.controller.limits.armed_poll_hz
            assert s.poller.poll_period_s == pytest.approx(idle_period_s)
            s.go()
            assert await _until(lambda: s.sim.model.throttle_frac == 1.0, 10)
            assert s.poller.poll_period_s == pytest.approx(1 / s.poller.full_poll_hz)
            s.estop("test")
            t_estop = s.sim.model.t_s
            m, act = s.sim.model, s.sim.actuators
            assert act.releasing and m.actuator_dir != STOP
            # the full release stroke (8 s of rig time, 1 s here) ends and the actuator is switched off
            assert await _until(lambda: not act.releasing and m.actuator_dir == STOP, 5), act.history[-3:]
            stroke_end = next(t for t, what, v in reversed(act.history) if what == "brake" and v == STOP)
            from dyno.sim.rig import RELEASE_MARGIN_FRACTION, RELEASE_MARGIN_S

            full_s = act.brake_full_stroke_s * (1 + RELEASE_MARGIN_FRACTION) + RELEASE_MARGIN_S  # stroke + margin
            assert stroke_end - t_estop == pytest.approx(full_s, abs=0.2)
            # full rate while the engine spins down, then the idle rate
            if m.truth().rpm_primary > 100:
                assert s.poller.poll_period_s == pytest.approx(1 / s.poller.full_poll_hz)
            assert await _until(lambda: s.poller.poll_period_s == pytest.approx(idle_period_s), 10)
            assert s.controller.state is State.ABORTED and act.is_safe
        finally:
            await s.close("test")

    asyncio.run(scenario())


def test_a_jog_under_way_when_the_rig_trips_cannot_stop_the_release(tmp_path):
    """The operator jogs the brake on (manual mode); the link is lost mid-jog. The jog's own end (its timer's
    STOP), the operator's next jog and the session's cancel all come after the safe state: each is refused and
    logged, and the physics' pads leave the rotor (the release runs to its end)."""
    from dyno.control.outputs import APPLY

    async def scenario():
        s = LiveSession(LiveOptions(sim=True, speed=2.0, seed=2, out_dir=tmp_path / "run", jog_s=2.0))
        s.start()
        try:
            assert await _until(lambda: s.controller.state is State.ARMED, 30), s.controller.reason
            m, act = s.sim.model, s.sim.actuators
            assert s.set_manual(True).startswith("manual mode")
            assert s.jog(APPLY) is None  # 2 s of rig time on the brake (1 s here), its STOP on a timer
            assert await _until(lambda: m.actuator_mm > 6.0, 5), m.actuator_mm  # well onto the rotor
            s.sim.bus.lost = True  # the cable falls out mid-jog
            assert await _until(lambda: s.controller.state is State.ABORTED, 5)
            assert "test finished" in s.jog(APPLY)  # the operator tries again: refused by the session
            assert not m.pads_off, "the release had already ended: this test would prove nothing"
            s.cancel_jog()  # ... and the pending jog's STOP goes through the controller's gate: refused
            assert await _until(lambda: m.pads_off and m.actuator_dir == STOP, 10), m.actuator_mm
            refused = [r for r in s.controller.refused if r["command"] == "brake" and r["value"] == STOP]
            assert refused, s.controller.refused
            assert act.latched and act.is_safe
        finally:
            await s.close("test")

    asyncio.run(scenario())
