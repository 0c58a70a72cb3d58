"""Test plans as data: TOML plan files (docs/control.md, "Plan files").

::

    schema = "dyno.plan/1"
    name = "speed-hold"
    description = "closed-loop secondary-speed setpoints, each point to a 95 % CI of +-1 pp"
    mode = "speed-hold"          # step | speed-hold | steps | any mode registered in dyno.control.plans

    [test]                       # TestPlan fields (measurement targets, caps, warm-up, stop speed, ...)
    target_efficiency_ci95 = 0.01
    [test.settle]                # SettleCriteria fields (mode "step")
    [speed_hold]                 # the mode's own table, named after the mode ("-" -> "_")
    [[step]]                     # mode "steps": the list of steps (dyno.control.plans.steps)

Every problem is a :class:`~dyno.errors.ConfigError` naming the file and the field.  The
plan keeps its file's text, which the run directory stores as ``plan.toml``.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

from dyno.control.api import TestPlan
from dyno.control.registry import known_modes, params_class
from dyno.control.steady import SettleCriteria
from dyno.errors import ConfigError

SCHEMA = "dyno.plan/1"
SHIPPED_DIR = Path(__file__).resolve().parent / "plan_files"
TOP_KEYS = {"schema", "name", "description", "mode", "test", "step"}
#: TestPlan fields a file may not set ([test] is for measurement settings; these come from elsewhere)
_NOT_IN_TEST = {"mode", "name", "params", "steps", "settle", "source", "text"}


def shipped_plans() -> dict[str, Path]:
    """The plan files shipped with the package, by name (file stem)."""
    return {p.stem: p for p in sorted(SHIPPED_DIR.glob("*.toml"))}


def load_plan_file(path) -> TestPlan:
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(path, "file", "a plan file (not found)") from None
    except IsADirectoryError:
        raise ConfigError(path, "file", "a plan file (got a directory)") from None
    except OSError as exc:
        raise ConfigError(path, "file", f"a readable plan file ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(path, f"byte {exc.start}", "UTF-8 TOML text") from None
    return plan_from_text(text, path)


def plan_from_text(text: str, path="plan") -> TestPlan:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(path, "toml", f"valid TOML ({exc})") from None
    return plan_from_dict(data, path, text=text)


def plan_from_dict(data: dict, path="plan", *, text: str = "") -> TestPlan:
    def err(field: str, expected: str) -> ConfigError:
        return ConfigError(path, field, expected)

    if data.get("schema") != SCHEMA:
        raise err("schema", f'"{SCHEMA}", got {data.get("schema")!r}')
    mode = data.get("mode")
    if not isinstance(mode, str) or mode not in known_modes():
        raise err("mode", f"one of {', '.join(sorted(known_modes()))}, got {mode!r}")
    name = data.get("name", Path(str(path)).stem)
    if not isinstance(name, str) or not name:
        raise err("name", f"a non-empty string, got {name!r}")
    if not isinstance(data.get("description", ""), str):
        raise err("description", "a string")
    table_key = mode.replace("-", "_")
    extra = set(data) - TOP_KEYS - {table_key}
    if extra:
        raise err(sorted(extra)[0], f"not a plan key (expected {', '.join(sorted(TOP_KEYS | {table_key}))})")

    test = data.get("test", {})
    if not isinstance(test, dict):
        raise err("test", "a table [test]")
    fields = {f.name: f for f in dataclasses.fields(TestPlan)}
    kw = {}
    for key, value in test.items():
        if key == "settle":
            kw["settle"] = _dataclass_from(SettleCriteria, value, "test.settle", err)
            continue
        if key not in fields or key in _NOT_IN_TEST:
            raise err(f"test.{key}", "not a test setting (see docs/control.md)")
        kw[key] = _typed(value, getattr(TestPlan(), key), f"test.{key}", err)

    table = data.get(table_key, {})
    if not isinstance(table, dict):
        raise err(table_key, f"a table [{table_key}]")
    params = None
    if mode == "steps":
        from dyno.control.plans.steps import StepsPlan, validate_steps

        raw = data.get("step")
        if not isinstance(raw, list) or not raw:
            raise err("step", "one or more [[step]] tables (mode \"steps\")")
        params = StepsPlan(steps=validate_steps(raw, err))
    elif "step" in data:
        raise err("step", f'[[step]] tables only with mode = "steps" (mode is {mode!r})')
    elif params_class(mode) is not None:
        params = _dataclass_from(params_class(mode), table, table_key, err)
        if hasattr(params, "check"):  # the mode's own checks beyond the types
            params.check(lambda field, expected: err(f"{table_key}.{field}", expected))
    elif table:
        params = dict(table)  # a mode registered in code without a parameter class: its table as given
    return TestPlan(mode=mode, name=name, params=params, source=str(path), text=text, **kw)


def _typed(value, default, field: str, err):
    """``value`` checked against the type of the field's default (numbers finite and >= 0)."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise err(field, f"true or false, got {value!r}")
        return value
    if isinstance(default, str):
        if not isinstance(value, str):
            raise err(field, f"a string, got {value!r}")
        if field.endswith("settle_mode") and value not in ("detect", "fixed"):
            raise err(field, f'"detect" or "fixed", got {value!r}')
        return value
    if isinstance(default, tuple):  # a list of numbers (e.g. [drive_grid] throttles)
        if (not isinstance(value, list) or not value or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0 for v in value)):
            raise err(field, f"a non-empty list of finite numbers >= 0, got {value!r}")
        return tuple(float(v) for v in value)
    if isinstance(default, int) or isinstance(default, float) or default is None:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise err(field, f"a number, got {value!r}")
        if not math.isfinite(value) or value < 0:
            raise err(field, f"a finite number >= 0, got {value!r}")
        if isinstance(default, int) and not isinstance(value, int):
            raise err(field, f"an integer, got {value!r}")
        if field.endswith("stop_quantile") and not 0.0 < value < 1.0:
            raise err(field, f"a probability between 0 and 1 (exclusive), got {value!r}")
        return float(value) if isinstance(default, float) else value
    raise err(field, "not settable from a plan file")


def _dataclass_from(cls, table, prefix: str, err):
    if not isinstance(table, dict):
        raise err(prefix, f"a table [{prefix}]")
    names = {f.name for f in dataclasses.fields(cls)}
    defaults = cls()
    kw = {}
    for key, value in table.items():
        if key not in names:
            raise err(f"{prefix}.{key}", f"one of {', '.join(sorted(names))}")
        kw[key] = _typed(value, getattr(defaults, key), f"{prefix}.{key}", err)
    return cls(**kw)


def canonical(plan: TestPlan) -> dict:
    """The plan as plain data (what meta.json keeps; its text goes to plan.toml)."""
    d = dataclasses.asdict(plan)
    d.pop("text", None)
    return d
