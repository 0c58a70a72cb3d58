"""The safe state is physical: after a mid-test fault on every shipped plan the brake pads are off the
rotor, the actuator de-energised, throttle idle and ignition killed — read from the simulated physics,
not from what the program says — and the latch refuses every command that would undo it."""

from __future__ import annotations

from dataclasses import replace

import pytest

from dyno.resources import DEFAULT_ENGINE_MAP
from dyno.session.root import RunSpec, run_test
from dyno.control.outputs import APPLY, RELEASE, STOP
from dyno.control.plans import plan_named
from dyno.session.drills import parse_drill
from dyno.errors import SafetyAbort

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

PART_THROTTLE_MAP = DEFAULT_ENGINE_MAP.with_name("baja-10hp-representative-part-throttle.csv")

# plan -> the mid-test drill: a different fault on each, at a phase where the brake is working
CASES = {
    "speed-hold": "bus-lost@loaded+3",
    "thesis-step": "adc-stuck@loaded+2",
    "torque-hold": "controller-crash@loaded+4",
    "engine-hold": "disk-full@loaded+3",
    "sweep": "thermometer-lost@loaded+1",
    "engagement": "hall-dead:secondary@loaded+0.5",
    "coast-down": "loop-stall:800@settle+1",
    "drive-grid": "adc-error@loaded+3",
}


def _run(plan: str, drill: str, tmp_path, *, mock_pins: bool = False, setup=None):
    held: dict = {}

    def keep(ctx):
        held["ctx"] = ctx
        if setup is not None:
            setup(ctx)

    opts = RunSpec(sim=True, seed=5, out_dir=tmp_path / f"{plan}-{mock_pins}", plan=plan_named(plan),
                      drills=[parse_drill(drill)], setup=keep, mock_pins=mock_pins)
    if plan == "drive-grid":
        opts = replace(opts, engine_map_path=PART_THROTTLE_MAP)
    return run_test(opts), held["ctx"]


def _assert_physically_safe(r: dict, ctx) -> None:
    m = ctx.sim.model
    b = m.brake
    assert m.actuator_mm <= b.a0_mm, f"pads on the rotor: actuator at {m.actuator_mm:.2f} mm"
    assert m.actuator_dir == STOP, "actuator still powered"
    assert m.throttle_frac == 0.0 and not m.engine_enabled
    assert r["rig_safe"] is True and r["outputs"]["safe"] is True
    out = r["outputs"]
    assert out["brake_position_mm"] == pytest.approx(m.actuator_mm, abs=1e-3)
    # the release in true time, within (position at the safe state - free travel) / speed + 0.2 s
    mm_at = out["brake_position_at_safe_mm"]
    assert out["release_bound_s"] == pytest.approx(max(0.0, mm_at - b.a0_mm) / b.v_act_mm_s + 0.2, abs=1e-6)
    assert out["release_s"] is not None and out["release_s"] <= out["release_bound_s"], out
    assert out["released_at_s"] is not None
    if mm_at > b.a0_mm:  # the pads were on the rotor when the safe state came: they left after it
        assert out["released_at_s"] >= out["safe_commanded_s"] - 1e-9


@pytest.mark.parametrize("plan", list(CASES))
def test_every_plan_mid_test_drill_leaves_the_pads_off_the_rotor(plan, tmp_path):
    r, ctx = _run(plan, CASES[plan], tmp_path)
    assert r["drills"] and r["drills"][0]["hazard_arose"] is True, r["drills"]
    assert r["state"] == "aborted", (r["state"], r["reason"])
    a = r["aborts"][0]
    # the brake was working when the fault came (except the coast-down, whose brake is released by design)
    if plan != "coast-down":
        assert a["brake_position_at_safe_mm"] > ctx.sim.model.brake.a0_mm, a
    _assert_physically_safe(r, ctx)
    assert a["release_within_bound"] is True


@pytest.mark.parametrize("plan", ["speed-hold", "thesis-step"])
def test_mock_pins_mid_test_drill_leaves_the_pads_off_the_rotor(plan, tmp_path):
    r, ctx = _run(plan, "bus-lost@loaded+3", tmp_path, mock_pins=True)
    assert r["state"] == "aborted"
    _assert_physically_safe(r, ctx)
    out = r["outputs"]
    # the shipped rig declares the end switch (hardware/rig.toml): the twin's switch closed at the stop
    assert out["driver_released"] is True and out["driver_release_basis"] == "end_of_travel"
    assert out["brake_estimate"] == 0.0


def test_the_latch_outlasts_plan_cleanup_ui_and_late_commands(tmp_path):
    """After the abort: the plan's own cleanup (its finally: STOP), a UI jog and a late controller command
    each try to move the brake; every one is refused and logged, and the release completes anyway."""
    tries: dict = {"ui": None, "late_stop": False, "late_apply": None}

    def setup(ctx):
        ctrl = ctx.controller

        def on_state(c):
            if c.state.value != "aborted" or tries["late_stop"]:
                return
            tries["late_stop"] = True
            c.brake(STOP)  # a late controller command: refused quietly
            c.brake(RELEASE)
            try:
                c.brake(APPLY)  # ... and an apply raises
            except SafetyAbort as exc:
                tries["late_apply"] = str(exc)
            try:  # something holding the raw actuators (a UI action): refused by the actuators' own latch
                ctx.sim.actuators.brake(STOP)
                ctx.sim.actuators.brake(APPLY)
            except SafetyAbort as exc:
                tries["ui"] = str(exc)

        ctrl.listeners.append(on_state)

    r, ctx = _run("speed-hold", "bus-lost@loaded+3", tmp_path, setup=setup)
    assert tries["late_stop"] and tries["late_apply"] and tries["ui"]
    refused = r["refused"]
    cmds = [(x["command"], x["value"]) for x in refused]
    # the plan's own cleanup (speed_hold's finally: brake(STOP)) hit the gate, as did the late commands
    assert cmds.count(("brake", STOP)) >= 2 and ("brake", APPLY) in cmds and ("brake", RELEASE) in cmds, cmds
    assert any(x.get("by") == "actuators" for x in refused)
    _assert_physically_safe(r, ctx)
    # the run directory records the same (drill, latency from the onset, physical outputs)
    from dyno.runlog.reader import load_run

    docs = load_run(r["run_dir"]).docs("safety")
    assert docs and docs[-1]["rig_safe"] is True and docs[-1]["drills"][0]["drill"] == "bus-lost@loaded+3"
    assert docs[-1]["aborts"][0]["latency_s"] == pytest.approx(r["aborts"][0]["latency_s"])
    assert docs[-1]["outputs"]["released_at_s"] == pytest.approx(r["outputs"]["released_at_s"])


def test_brake_hold_relay_releases_without_software(tmp_path):
    """K3 fitted: the ignition killed powers the actuator in release through the relay's NC contacts, even
    when the software never releases (a driver stuck: every brake command dropped)."""
    import dataclasses

    from dyno.sim.rig import SimActuators

    def setup(ctx):
        ctx.sim.model.brake_hold_relay = True
        # the software's release never reaches the actuator: its safe state only kills the ignition
        act = ctx.sim.actuators

        def kill_only(latch=False):
            act.wiring.engine_kill(True)
            act.wiring.throttle(0.0)
            act.wiring.brake(STOP)

        act.safe_state = kill_only
        assert isinstance(act, SimActuators)

    r, ctx = _run("speed-hold", "bus-lost@loaded+3", tmp_path, setup=setup)
    assert dataclasses.is_dataclass(ctx.rig_cfg)
    m = ctx.sim.model
    assert m.actuator_mm <= m.brake.a0_mm and r["rig_safe"] is True


def test_a_crash_raised_in_a_plans_helper_task_still_ends_in_the_safe_state(tmp_path):
    """Found by bench_safety: the crash injected mid-measure on torque-hold was raised in the hold loop's task
    while the plan task was cancelled; the run ended in state MEASURE, throttle open, no abort. The engine now
    has the last word: a plan that ends without finishing is an abort to the safe state."""
    r, ctx = _run("torque-hold", "controller-crash@measure+1", tmp_path)
    assert r["state"] == "aborted" and r["aborts"][0]["cause"] == "error", (r["state"], r["aborts"])
    _assert_physically_safe(r, ctx)
