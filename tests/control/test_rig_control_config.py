"""rig.toml [control] and [inertia]: the repo's values reach the holds; bad ones name their field."""

import copy
import tomllib

import pytest

from dyno.control.hold_law import HoldGains
from dyno.errors import ConfigError
from dyno.rig.config import DEFAULT_RIG_PATH, ControlConfig, rig_from_dict
from dyno.rig.inertia import InertiaConfig

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


@pytest.fixture(scope="module")
def base():
    with open(DEFAULT_RIG_PATH, "rb") as fh:
        return tomllib.load(fh)


def test_gains_and_inertias_from_rig_toml(base):
    d = copy.deepcopy(base)
    d["control"]["kp_speed"] = 4.5
    d["control"]["kp_torque"] = 0.7
    d["inertia"]["secondary_kg_m2"] = 0.02
    rig = rig_from_dict(d, "r.toml")
    assert HoldGains.from_config(rig.control, "secondary").kp == 4.5
    assert HoldGains.from_config(rig.control, "torque").kp == 0.7
    assert rig.inertia.secondary_kg_m2 == 0.02
    for k in ("control", "inertia", "uncertainty"):  # optional tables: defaults without them
        d.pop(k)
    rig = rig_from_dict(d, "r.toml")
    assert rig.control == ControlConfig() and rig.inertia == InertiaConfig()


@pytest.mark.parametrize("table, key, value", [
    ("control", "kp_speed", 0.0), ("control", "kp_speed", float("nan")), ("control", "period_s", 5.0),
    ("control", "min_pulse_s", 0.08), ("control", "kp_sped", 3.0), ("inertia", "engine_kg_m2", -0.1),
    ("inertia", "engine_kg_m2", "heavy"), ("uncertainty", "engine_map_rel", 1.5), ("uncertainty", "map", 0.1),
])
def test_bad_control_or_inertia_names_its_field(base, table, key, value):
    d = copy.deepcopy(base)
    d[table][key] = value
    with pytest.raises(ConfigError) as exc:
        rig_from_dict(d, "bad.toml")
    assert exc.value.field == f"{table}.{key}" and "\n" not in str(exc.value)
