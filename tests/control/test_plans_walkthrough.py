"""docs/plans.md's walk-through, run as written: its module and plan files taken from the page, the modes
registered as the page says, each plan run on the fake rig and judged by the fake plant's truth."""

from __future__ import annotations

import re
import sys
from pathlib import Path
from types import MappingProxyType

import pytest

from dyno.control import registry
from dyno.control.api import State
from dyno.control.fake_rig import FakeRig
from dyno.control.outputs import APPLY, STOP
from dyno.control.planfile import load_plan_file, plan_from_text
from dyno.errors import ConfigError

pytestmark = pytest.mark.quick

DOC = Path(__file__).resolve().parents[2] / "docs" / "plans.md"


def _blocks() -> dict[str, str]:
    """The page's files: each fenced block after a ``<!-- walkthrough: NAME -->`` marker."""
    text = DOC.read_text()
    found = dict(re.findall(r"<!-- walkthrough: (\S+) -->\n```\w+\n(.*?)```", text, re.S))
    assert set(found) == {"my_plans.py", "brake-pulses.toml", "torque-ladder.toml"}, sorted(found)
    return found


@pytest.fixture
def walkthrough(tmp_path, monkeypatch):
    files = _blocks()
    for name, body in files.items():
        (tmp_path / name).write_text(body)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "my_plans", raising=False)
    # the page's registration: a line in each of registry.RUNNERS and registry.PARAMS
    monkeypatch.setattr(registry, "RUNNERS", MappingProxyType({
        **registry.RUNNERS, "brake-pulses": "my_plans:run_brake_pulses", "torque-ladder": "my_plans:run_torque_ladder"}))
    monkeypatch.setattr(registry, "PARAMS", MappingProxyType({
        **registry.PARAMS, "brake-pulses": "my_plans:BrakePulsesPlan", "torque-ladder": "my_plans:TorqueLadderPlan"}))
    return tmp_path


def _safe(rig: FakeRig) -> None:
    p = rig.plant
    assert p.pads_off and p.brake_dir == STOP and not p.ignition and p.throttle == 0.0


def test_the_open_loop_plan_of_the_walkthrough_runs_on_the_fake_rig(walkthrough):
    plan = load_plan_file(walkthrough / "brake-pulses.toml")
    assert type(plan.params).__name__ == "BrakePulsesPlan" and plan.params.pulses == 4
    rig = FakeRig(plan)
    seen: list[float] = []  # the brake's true position at each point's end (the plant, not the engine)
    rig.controller.point_hooks.append(lambda point, t0, t1: seen.append(rig.plant.brake_pos))
    assert rig.run() is State.DONE, rig.controller.aborts
    c = rig.controller
    assert len(c.points) == 4 and len(seen) == 4
    assert all(b > a for a, b in zip(seen, seen[1:]))  # each pulse moved the brake further on
    brakes = rig.act.commands("brake")
    assert brakes.count(APPLY) >= 4  # (the engine's start-up release aside)
    torques = [p["torque_secondary_nm"] for p in c.points]
    assert all(b > a for a, b in zip(torques, torques[1:]))
    _safe(rig)


def test_the_closed_loop_plan_of_the_walkthrough_holds_each_torque(walkthrough):
    plan = load_plan_file(walkthrough / "torque-ladder.toml")
    assert plan.params.torques_nm == (6.0, 10.0, 14.0)
    rig = FakeRig(plan)
    truth: list[float] = []  # the plant's own brake torque at each point's end
    rig.controller.point_hooks.append(lambda point, t0, t1: truth.append(rig.plant.brake_torque_nm))
    assert rig.run() is State.DONE, rig.controller.aborts
    assert len(truth) == 3
    for nm, true_nm in zip((6.0, 10.0, 14.0), truth):
        assert true_nm == pytest.approx(nm, rel=0.06), truth  # held within the hold's band (3 %) and its window
    assert rig.act.commands("brake").count(APPLY) >= 10  # a pulse train: the loop, not one move
    _safe(rig)


def test_the_walkthroughs_plan_file_is_checked_against_its_parameters(walkthrough):
    bad = (walkthrough / "torque-ladder.toml").read_text().replace("torques_nm", "torque_nm")
    with pytest.raises(ConfigError, match=r"torque_ladder\.torque_nm"):
        plan_from_text(bad, "torque-ladder.toml")
