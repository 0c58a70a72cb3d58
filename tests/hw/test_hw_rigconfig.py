"""rig.toml validation: the repo's file loads; every bad case names its field."""

import copy
import tomllib

import pytest

from dyno.errors import ConfigError
from dyno.rig.config import DEFAULT_RIG_PATH, load_rig, rig_from_dict

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


@pytest.fixture(scope="module")
def base():
    with open(DEFAULT_RIG_PATH, "rb") as fh:
        return tomllib.load(fh)


def test_hw_repo_rig_loads():
    rig = load_rig()
    assert rig.i2c.firmware_address == 0x03 and rig.i2c.thermometer_address == 0x5A
    assert rig.gear_ratio_brake_per_secondary == pytest.approx(32 / 61)
    assert (rig.debounce_primary_us, rig.debounce_secondary_us) == (1000, 1000)  # v2 lock-out floors
    assert rig.poll_hz == 150 and rig.protocol in ("v2", "v1", "v0")
    assert len(set(rig.pins.as_dict().values())) == 5


def test_hw_board_pin_names_convert(base):
    d = copy.deepcopy(base)
    d["pins"]["brake_enable"] = "BOARD33"
    d["pins"]["brake_direction"] = "GPIO23"
    rig = rig_from_dict(d)
    assert rig.pins.brake_enable == 13 and rig.pins.brake_direction == 23


BAD = [
    ("unknown pin", lambda d: d["pins"].__setitem__("brake_enable", 40), "pins.brake_enable"),
    ("unknown pin name", lambda d: d["pins"].__setitem__("throttle_servo", "BOARD1"), "pins.throttle_servo"),
    ("i2c pin", lambda d: d["pins"].__setitem__("engine_kill", 3), "pins.engine_kill"),
    ("duplicate pin", lambda d: d["pins"].__setitem__("arduino_reset", d["pins"]["brake_enable"]),
     "pins.arduino_reset"),
    ("address high", lambda d: d["i2c"].__setitem__("firmware_address", 0x78), "i2c.firmware_address"),
    ("address low", lambda d: d["i2c"].__setitem__("thermometer_address", 0x02), "i2c.thermometer_address"),
    ("missing field", lambda d: d["limits"].pop("rotor_temp_max_c"), "limits.rotor_temp_max_c"),
    ("missing table", lambda d: d.pop("pins"), "pins"),
    ("wrong type", lambda d: d.__setitem__("poll_hz", "fast"), "poll_hz"),
    ("unknown key", lambda d: d["actuator"].__setitem__("stepp_s", 1.0), "actuator.stepp_s"),
    ("bad protocol", lambda d: d.__setitem__("protocol", "v3"), "protocol"),
    ("servo in ms", lambda d: d["throttle"].__setitem__("idle_pulse_us", 2.2), "throttle.idle_pulse_us"),
    # an infinite limit disables its trip; NaN compares false; inf polling hangs the loop
    ("inf limit", lambda d: d["limits"].__setitem__("rotor_temp_max_c", float("inf")), "limits.rotor_temp_max_c"),
    ("nan limit", lambda d: d["limits"].__setitem__("overspeed_primary_rpm", float("nan")),
     "limits.overspeed_primary_rpm"),
    ("limit out of range", lambda d: d["limits"].__setitem__("comms_timeout_s", 60.0), "limits.comms_timeout_s"),
    ("inf poll rate", lambda d: d.__setitem__("poll_hz", float("inf")), "poll_hz"),
    ("zero poll rate", lambda d: d.__setitem__("poll_hz", 0), "poll_hz"),
    ("watchdog off", lambda d: d["actuator"].__setitem__("watchdog_s", float("inf")), "actuator.watchdog_s"),
    ("estop pin taken", lambda d: d["pins"].__setitem__("estop_input", d["pins"]["engine_kill"]), "pins.estop_input"),
]


@pytest.mark.parametrize("case,mutate,field", BAD, ids=[b[0] for b in BAD])
def test_hw_bad_rig_names_field(base, case, mutate, field):
    d = copy.deepcopy(base)
    mutate(d)
    with pytest.raises(ConfigError) as exc:
        rig_from_dict(d, "bad.toml")
    assert exc.value.field == field
    assert "\n" not in str(exc.value) and str(exc.value).startswith("bad.toml: " + field)
    if "range" in case or "inf" in case or "nan" in case or "zero" in case or "off" in case:
        assert ".." in str(exc.value)  # the allowed range is stated


def test_hw_missing_file(tmp_path):
    with pytest.raises(ConfigError) as exc:
        load_rig(tmp_path / "nope.toml")
    assert exc.value.field == "file"


def test_hw_invalid_toml(tmp_path):
    p = tmp_path / "rig.toml"
    p.write_text("pins = [\n")
    with pytest.raises(ConfigError) as exc:
        load_rig(p)
    assert exc.value.field == "toml"
