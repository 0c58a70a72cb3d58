"""The engine and the plans on the fake rig (dyno/control/fake_rig.py): the state table, the output
gate, the engine's last word after an abort, each plan's commands — judged by the fake plant's truth and
the actuators' record, in well under a second each."""

from __future__ import annotations

import tokenize
import time
from pathlib import Path

import pytest

from dyno.control.api import TRANSITIONS, PlanContext, State
from dyno.control.api import TestPlan as Plan
from dyno.control.engine import EngineContext
from dyno.control.outputs import APPLY, RELEASE, STOP
from dyno.control.plans import plan_named
from dyno.control.safety import SafetyLimits
from dyno.errors import SafetyAbort

from dyno.control.fake_rig import FakeRig

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

PLANS_DIR = Path(__file__).resolve().parents[2] / "dyno" / "control" / "plans"


def _legal(states: list[str]) -> bool:
    seq = [State.IDLE] + [State(s) for s in states]
    return all(b in TRANSITIONS[a] or a == b for a, b in zip(seq, seq[1:]))


def _assert_safe_at_the_end(rig: FakeRig) -> None:
    """The plant's truth: pads off the rotor, the actuator stopped, ignition off, throttle idle."""
    p = rig.plant
    assert p.pads_off and p.brake_pos == 0.0 and p.brake_dir == STOP, (p.brake_pos, p.brake_dir)
    assert p.ignition is False and p.throttle == 0.0


def _after_last_safe_state(rig: FakeRig) -> list:
    log = rig.act.log
    i = max(k for k, (_, what, latch) in enumerate(log) if what == "safe_state" and latch)
    return log[i + 1:]


@pytest.mark.parametrize("name", ["thesis-step", "speed-hold", "torque-hold", "sweep", "drive-grid",
                                  "engagement", "coast-down"])
def test_every_plan_runs_its_commands_on_the_fake_rig_and_leaves_it_safe(name):
    t0 = time.perf_counter()
    rig = FakeRig(plan_named(name))
    rig_t0 = rig.loop.time()
    state = rig.run()
    wall_s, rig_s = time.perf_counter() - t0, rig.loop.time() - rig_t0
    c = rig.controller
    assert state is State.DONE, (c.reason, c.aborts)
    assert rig.states[:2] == ["wait_engine", "armed"] and rig.states[-1] == "done" and _legal(rig.states)
    _assert_safe_at_the_end(rig)
    assert not [e for e in _after_last_safe_state(rig) if e[1] in ("brake", "throttle", "engine_kill")]
    assert wall_s < rig_s / 5, (wall_s, rig_s)  # on the virtual clock: no plan waits in wall time
    brakes = rig.act.commands("brake")
    if name == "thesis-step":  # open-loop steps: apply, stop, ... never a release until the end
        assert set(brakes[1:]) == {APPLY, STOP} and all(a != b for a, b in zip(brakes[1:], brakes[2:]))
        torques = [p["torque_secondary_nm"] for p in c.points]
        assert len(torques) >= 5 and all(b > a for a, b in zip(torques, torques[1:]))  # each step loads more
    elif name in ("speed-hold", "torque-hold"):  # closed loop: a pulse train, a point a setpoint
        assert brakes.count(APPLY) >= 20 and len(c.points) >= 5
    elif name == "drive-grid":  # a pulse train per cell; the brake released before each throttle's row
        # (the fake plant is no CVT: several cells of the grid lie where its crude map cannot be held, and how many
        # depends on where the 100 ms kill-path probes put GO; each cell ends as a point or a skip naming why)
        assert brakes.count(APPLY) >= 20 and len(c.points) >= 3 and RELEASE in brakes
        assert len(c.points) + len(c.skips) >= 10 and all(c.skips), (c.points, c.skips)
    elif name == "coast-down":  # the engine cut on purpose, the brake never applied
        assert APPLY not in brakes
        assert any(w == "safe_state" and latch is False for t, w, latch in rig.act.log if t > c.go_s)
        assert c.results["loss_fit"]["rpm_max"] > c.results["loss_fit"]["rpm_min"] > 0
    elif name == "engagement":  # a throttle ramp from idle
        ramp = [f for f in rig.act.commands("throttle") if 0 < f < 1]
        assert len(ramp) >= 10 and ramp[:5] == sorted(ramp[:5])
        assert c.results["engagement_rpm"] > 0


def test_the_gate_refuses_a_plans_outputs_after_its_own_failure():
    seen: dict = {}

    async def runner(ctx, params=None):
        ctx.throttle(1.0)
        ctx.brake(APPLY)
        await ctx.sleep(1.0)
        ctx.brake(STOP)
        seen["pos_at_fail"] = rig.plant.brake_pos
        ctx.fail("error", "test: the plan's own failure")
        with pytest.raises(SafetyAbort):
            ctx.brake(APPLY)
        with pytest.raises(SafetyAbort):
            ctx.throttle(0.5)
        ctx.brake(STOP)  # refused quietly: a plan's cleanup must not stop the release stroke
        seen["done"] = True

    rig = FakeRig(Plan(mode="gate-test"), runner_for=lambda mode: runner)
    assert rig.run() is State.ABORTED
    c = rig.controller
    assert seen["done"] and seen["pos_at_fail"] > rig.plant.free_travel  # the brake was on the rotor
    assert c.aborts[0]["cause"] == "error" and [r["command"] for r in c.refused] == ["brake", "throttle", "brake"]
    assert not [e for e in _after_last_safe_state(rig) if e[1] in ("brake", "throttle", "engine_kill")]
    _assert_safe_at_the_end(rig)


def test_the_engine_has_the_last_word_over_a_runaway_and_a_plans_rogue_task():
    """A plan that never returns, its engine-owned task pulsing the brake and trying to apply it again
    on its way out; the engine runs away (a failed governor): the over-speed trip safes the rig within a
    poll, the engine cancels the task, its apply is refused, and the plant ends released and killed."""
    seen: dict = {}

    async def runner(ctx, params=None):
        async def rogue_hold():  # keeps trying whatever is refused: only the engine can end it
            seen["refused"] = 0
            try:
                while True:
                    try:
                        ctx.brake(APPLY)
                    except SafetyAbort:
                        seen["refused"] += 1
                    await ctx.sleep(0.05)
                    ctx.brake(STOP)
                    await ctx.sleep(0.05)
            finally:
                try:
                    ctx.brake(APPLY)
                except SafetyAbort:
                    seen["cleanup_refused"] = True

        rig.loop.call_later(2.0, lambda: setattr(rig.plant, "governor_failed", True))
        await ctx.bounded(rogue_hold(), lambda: None)  # a step no limit ends: only the engine can

    rig = FakeRig(Plan(mode="runaway-test"), runner_for=lambda mode: runner,
                  limits=SafetyLimits(overspeed_primary_rpm=4300.0))
    assert rig.run() is State.ABORTED
    c = rig.controller
    (abort,) = c.aborts
    assert abort["cause"] == "overspeed" and abort["latency_s"] <= rig.poller.poll_period_s + 1e-9
    assert seen["cleanup_refused"]  # the engine cancelled the step, and its apply on the way out was refused
    assert not [e for e in _after_last_safe_state(rig) if e[1] in ("brake", "throttle", "engine_kill")]
    assert rig.act.latched
    _assert_safe_at_the_end(rig)


def test_the_engine_context_is_a_plan_context():
    rig = FakeRig()
    try:
        assert isinstance(rig.controller.plan_context, EngineContext)
        assert isinstance(rig.controller.plan_context, PlanContext)
    finally:
        rig.loop.close()


def _protocol_members() -> set[str]:
    return {n for n in dir(PlanContext) if not n.startswith("_")} | set(PlanContext.__annotations__)


def _code_tokens(path: Path) -> list:
    """The file's tokens, comments and strings aside (tokenize, not ast: CPython 3.11.7's parser can fail
    with "AST constructor recursion depth mismatch" after other tests in the process)."""
    with path.open("rb") as f:
        return [t for t in tokenize.tokenize(f.readline)
                if t.type not in (tokenize.COMMENT, tokenize.STRING, tokenize.NL, tokenize.NEWLINE)]


def test_the_plans_touch_nothing_but_the_plan_context():
    """Every attribute a plan module reads on its context is a PlanContext member; no plan imports the engine,
    starts a task of its own, or opens a file."""
    members = _protocol_members()
    modules = sorted(PLANS_DIR.glob("*.py"))
    assert len(modules) >= 8
    used = set()
    for path in modules:
        toks = _code_tokens(path)
        for a, b, c in zip(toks, toks[1:], toks[2:]):
            if a.string == "ctx" and b.string == "." and c.type == tokenize.NAME:
                assert c.string in members, f"{path.name}:{c.start[0]}: ctx.{c.string} is not in the plan context"
                used.add(c.string)
            if b.string == "." and c.string in ("create_task", "ensure_future", "gather", "cancel", "write_text",
                                                "read_text", "read_bytes", "controller", "engine", "streams"):
                raise AssertionError(f"{path.name}:{c.start[0]}: .{c.string}")
            if c.string == "open" and b.string != ".":
                raise AssertionError(f"{path.name}:{c.start[0]}: open()")
    assert {"phase", "measure", "record", "hold", "bounded", "fail", "brake"} <= used  # (the scan sees the plans' calls)


def test_the_plan_context_is_narrow_and_typed():
    """At most 20 members, each typed (an annotated attribute, or a method with every parameter and its
    return annotated), and a configuration of typed fields (issue 50: 28 members and 12 ``object`` fields
    before)."""
    import dataclasses
    import inspect

    from dyno.control.api import PlanConfig

    members = _protocol_members()
    assert len(members) <= 20, sorted(members)
    for name in sorted(members):
        if name in PlanContext.__annotations__:
            assert PlanContext.__annotations__[name] not in ("object", "Any"), name
            continue
        sig = inspect.signature(getattr(PlanContext, name))
        assert sig.return_annotation is not inspect.Signature.empty, name
        for p in list(sig.parameters.values())[1:]:
            if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL):
                assert p.annotation is not inspect.Parameter.empty, f"{name}({p.name})"
    types = {f.name: f.type for f in dataclasses.fields(PlanConfig)}
    assert types and not [n for n, t in types.items() if t in ("object", object, "Any")], types


def test_every_plan_annotates_its_context():
    """Every runner and helper of the plan modules that takes the context says it is a PlanContext."""
    import ast

    for path in sorted(PLANS_DIR.glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for arg in node.args.args:
                    if arg.arg == "ctx":
                        assert arg.annotation is not None and ast.unparse(arg.annotation) == "PlanContext", \
                            f"{path.name}:{node.lineno} {node.name}"
