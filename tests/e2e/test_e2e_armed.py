"""ARMED (engine idling, waiting for GO) and WAIT_ENGINE poll at ``armed_poll_hz``; every fault there still trips
within its bound.

The slower rate is what brings the idle CPU down (bench/bench_ui.py); these drills, with onset while the
controller waits in ARMED, measure the latency in true simulated time from the physical onset.
"""

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.control.safety import SafetyLimits
from dyno.session.drills import parse_drill

from .conftest import QUICK_PLAN

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

ONSET_S = 10.0  # after the first frame: the engine is running and the controller waits in ARMED

# drill -> (causes accepted, bound on latency_s), the same bounds as docs/safety.md
ARMED_DRILLS = {
    "adc-error": ({"sensor_fault"}, 0.1),
    "overspeed": ({"overspeed"}, 0.1),
    "hall-dead:primary": ({"sensor_fault", "stall"}, 0.5),
    "bus-lost": ({"comms_lost"}, 0.25 + 0.1),
}


def _armed_run(tmp_path, drill: str):
    captured = {}

    def setup(ctx):
        captured["ctx"] = ctx
        periods = captured["periods"] = []
        poller = ctx.poller
        ctx.controller.listeners.append(lambda c: periods.append((c.state.value, poller.poll_period_s)))

    r = run_test(RunSpec(sim=True, seed=3, out_dir=tmp_path / "run", plan=QUICK_PLAN, auto_go=False,
                            drills=[parse_drill(f"{drill}@{ONSET_S:g}")], setup=setup, max_sim_s=60.0))
    return r, captured["ctx"], captured["periods"]


@pytest.mark.parametrize("drill", sorted(ARMED_DRILLS))
def test_a_fault_while_armed_trips_within_its_bound_at_the_armed_poll_rate(tmp_path, drill):
    causes, bound_s = ARMED_DRILLS[drill]
    r, ctx, periods = _armed_run(tmp_path, drill)
    assert r["state"] == "aborted"
    a = r["aborts"][0]
    assert a["state"] == "armed", "the fault must strike while ARMED"
    assert a["cause"] in causes
    assert 0 <= a["latency_s"] <= bound_s, a
    # the poll rate was the ARMED rate while armed, and back to full once aborted
    armed_hz = SafetyLimits().armed_poll_hz
    assert ("armed", pytest.approx(1 / armed_hz)) in periods
    assert periods[-1] == ("aborted", pytest.approx(1 / ctx.poller.full_poll_hz))
    m = ctx.sim.model
    assert m.throttle_frac == 0.0 and not m.engine_enabled


def test_go_restores_the_full_poll_rate(tmp_path):
    periods = []

    def setup(ctx):
        poller = ctx.poller
        ctx.controller.listeners.append(lambda c: periods.append((c.state.value, poller.poll_period_s)))

    r = run_test(RunSpec(sim=True, seed=3, out_dir=tmp_path / "run", plan=QUICK_PLAN, setup=setup))
    assert r["state"] == "done"
    by_state = dict(periods)
    assert by_state["armed"] == pytest.approx(1 / SafetyLimits().armed_poll_hz)
    assert by_state["wait_engine"] == pytest.approx(1 / SafetyLimits().armed_poll_hz)  # waiting for the operator too
    for state in ("warmup", "step", "settle", "measure", "done"):
        assert by_state[state] == pytest.approx(1 / 150.0), state
