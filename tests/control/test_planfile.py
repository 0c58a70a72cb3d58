"""Plan files: the shipped ones load, bad ones name file and field, modes registered in code are usable."""

from dataclasses import replace

import pytest

from dyno.control.api import TestPlan as Plan
from dyno.control.planfile import load_plan_file, plan_from_text, shipped_plans
from dyno.control.plans import plan_named, plan_names
from dyno.control.plans.speed_hold import SpeedHoldPlan
from dyno.control.plans.steps import StepsPlan
from dyno.errors import ConfigError

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

HEAD = 'schema = "dyno.plan/1"\nname = "mine"\n'


def test_shipped_plans_load_by_name():
    names = plan_names()
    assert {"thesis-step", "speed-hold", "sweep", "torque-hold", "engine-hold"} <= set(names)
    for name in shipped_plans():
        plan = plan_named(name)
        assert plan.name == name and plan.text and plan.source.endswith(f"{name}.toml")
    step = plan_named("thesis-step")
    # the shipped thesis plan is the thesis test the code always ran (only identity fields differ)
    assert replace(step, name="", source="", text="") == Plan()
    hold = plan_named("speed-hold")
    assert hold.mode == "speed-hold" and hold.target_efficiency_ci95 <= 0.01 and hold.warmup_at_load_s > 0
    assert isinstance(hold.params, SpeedHoldPlan) and hold.params.points == 19  # the file's [speed_hold] table, typed
    sweep = plan_named("sweep")
    assert sweep.mode == "steps" and isinstance(sweep.params, StepsPlan) and [s["kind"] for s in sweep.params.steps] == ["contact", "ramp"]


def test_overrides_and_paths(tmp_path):
    assert plan_named("speed-hold", settle_mode="fixed").settle_mode == "fixed"
    f = tmp_path / "p.toml"
    f.write_text(HEAD + 'mode = "steps"\n[test]\nmeasure_s = 2.5\n[[step]]\nkind = "wait"\ns = 1\n')
    p = plan_named(str(f))
    assert p.name == "mine" and p.measure_s == 2.5 and p.params.steps == ({"kind": "wait", "s": 1},)
    assert p.text == f.read_text()


@pytest.mark.parametrize("body, field", [
    ('schema = "dyno.plan/2"\nmode = "step"\n', "schema"),
    (HEAD + 'mode = "warp"\n', "mode"),
    (HEAD + 'mode = "step"\nspeed = 3\n', "speed"),
    (HEAD + 'mode = "step"\n[test]\nmeasure_s = -1\n', "test.measure_s"),
    (HEAD + 'mode = "step"\n[test]\nmeasure_s = "3"\n', "test.measure_s"),
    (HEAD + 'mode = "step"\n[test]\nmode = "step"\n', "test.mode"),
    (HEAD + 'mode = "step"\n[test]\nmax_points = 2.5\n', "test.max_points"),
    (HEAD + 'mode = "step"\n[test]\nstop_quantile = 1.0\n', "test.stop_quantile"),
    (HEAD + 'mode = "step"\n[test]\nstop_quantile = 0\n', "test.stop_quantile"),
    (HEAD + 'mode = "step"\n[test.settle]\nwindow_s = true\n', "test.settle.window_s"),
    (HEAD + 'mode = "speed-hold"\n[speed_hold]\npoints = 2.5\n', "speed_hold.points"),
    (HEAD + 'mode = "speed-hold"\n[speed_hold]\npoint = 20\n', "speed_hold.point"),
    (HEAD + 'mode = "steps"\n', "step"),
    (HEAD + 'mode = "step"\n[[step]]\nkind = "wait"\ns = 1\n', "step"),
    (HEAD + 'mode = "steps"\n[[step]]\nkind = "jump"\n', "step[1].kind"),
    (HEAD + 'mode = "steps"\n[[step]]\nkind = "wait"\n', "step[1].s"),
    (HEAD + 'mode = "steps"\n[[step]]\nkind = "wait"\ns = 1\n[[step]]\nkind = "hold"\nsetpoint = -5\n',
     "step[2].setpoint"),
    (HEAD + 'mode = "steps"\n[[step]]\nkind = "hold"\nvariable = "rotor"\nsetpoint = 5\n', "step[1].variable"),
    (HEAD + 'mode = "steps"\n[[step]]\nkind = "hold"\n', "step[1].setpoint"),
    (HEAD + 'mode = "steps"\n[[step]]\nkind = "ramp"\nto = 2000\nrate_rpm_s = 100\non_limit = "x"\n',
     "step[1].on_limit"),
    (HEAD + 'mode = "steps"\n[[step]]\nkind = "ramp"\nto = 2000\n', "step[1].rate_rpm_s"),
    (HEAD + 'mode = "steps"\n[[step]]\nkind = "identify"\n', "step[1].setpoint"),
    (HEAD + 'mode = "steps"\n[[step]]\nkind = "identify"\nsetpoint = 3000\napply = 1\n', "step[1].apply"),
    (HEAD + 'mode = "steps"\n[[step]]\nkind = "identify"\nvariable = "torque"\nsetpoint = 16\n',
     "step[1].variable"),  # no auto-tune for the torque hold (docs/control.md)
    (HEAD + 'mode = [1\n', "toml"),
])
def test_bad_plan_files_name_file_and_field(tmp_path, body, field):
    f = tmp_path / "bad.toml"
    f.write_text(body)
    with pytest.raises(ConfigError) as exc:
        load_plan_file(f)
    assert exc.value.path == str(f) and exc.value.field == field, str(exc.value)


def test_unknown_name_and_missing_file():
    with pytest.raises(ConfigError) as exc:
        plan_named("no-such-plan")
    assert exc.value.field == "--plan" and "speed-hold" in exc.value.expected
    with pytest.raises(ConfigError) as exc:
        plan_named("nowhere/plan.toml")
    assert exc.value.field == "file"


def test_a_mode_registered_in_code_is_selectable_and_usable_from_a_file(monkeypatch):
    """Another module adds a mode (e.g. "endurance"): a code plan by name, and plan files may use it."""
    from types import MappingProxyType

    from dyno.control import registry

    # (the table is read-only: another module's mode is a different table, as a build of the package would ship)
    monkeypatch.setattr(registry, "RUNNERS",
                        MappingProxyType({**registry.RUNNERS, "endurance": "dyno.control.plans.steps:run_steps"}))
    monkeypatch.setitem(registry.PLANS, "endurance", Plan(mode="endurance", warmup_s=1.0))
    p = plan_named("endurance")
    assert p.mode == "endurance" and p.name == "endurance" and p.warmup_s == 1.0
    assert registry.runner_for("endurance").__name__ == "run_steps"
    f = plan_from_text(HEAD + 'mode = "endurance"\n[endurance]\nthrottle_rate = 0.1\n', "e.toml")
    assert f.mode == "endurance" and f.params == {"throttle_rate": 0.1}  # (a mode without a parameter class: its table as given)
    with pytest.raises(ConfigError):
        registry.runner_for("warp")
