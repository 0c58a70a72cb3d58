"""Tune file loading and validation."""

import tomllib
from pathlib import Path

import pytest

from dyno.errors import ConfigError
from dyno.tuning.tune import dumps_tune, load_tune, tune_from_dict

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "calibration/tunes/cvtech-stock-first-estimate.toml"


def _raw():
    return tomllib.loads(EXAMPLE.read_text())


def test_example_tune_loads_with_thesis_values():
    t = load_tune(EXAMPLE)
    assert t.flyweights.count == 3 and t.flyweights.mass_each_kg == 0.228
    assert t.drive.primary_radius_max_m == 0.093
    assert t.primary_spring.rate_n_per_m == 18200.0
    assert t.helix.angle_from_axis_deg == pytest.approx(50.0)  # 40 deg from the rotation plane


def test_round_trip_through_toml_text():
    t = load_tune(EXAMPLE)
    assert tune_from_dict(tomllib.loads(dumps_tune(t))) == t


def test_with_changes_dotted():
    t = load_tune(EXAMPLE)
    t2 = t.with_changes(**{"flyweights.mass_each_kg": 0.25, "primary_spring.rate_n_per_m": 20000.0})
    assert t2.flyweights.mass_each_kg == 0.25 and t2.primary_spring.rate_n_per_m == 20000.0
    assert t.flyweights.mass_each_kg == 0.228


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d["primary"]["flyweights"].pop("mass_each_kg"), "primary.flyweights.mass_each_kg"),
    (lambda d: d["primary"]["flyweights"].__setitem__("mass_each_kg", "heavy"), "primary.flyweights.mass_each_kg"),
    (lambda d: d["primary"]["flyweights"].__setitem__("mass_each_g", 228), "primary.flyweights.mass_each_g"),
    (lambda d: d["primary"]["flyweights"].__setitem__("count", 0), "primary.flyweights.count"),
    (lambda d: d["primary"]["flyweights"].__setitem__("washer_mass_each_kg", 0.5), "primary.flyweights.washer_mass_each_kg"),
    (lambda d: d["primary"]["flyweights"].__setitem__("washer_mass_each_kg", -0.001),
     "primary.flyweights.washer_mass_each_kg"),
    (lambda d: d["primary"]["flyweights"].__setitem__("sheave_travel_m", [0, 0.02, 0.01, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08]),
     "primary.flyweights.sheave_travel_m"),
    (lambda d: d["primary"]["flyweights"].__setitem__("sheave_travel_m", [0, 0.001, 0.002, 0.003, 0.004, 0.005, 0.006, 0.007, 0.008]),
     "primary.flyweights.sheave_travel_m"),
    (lambda d: d["primary"]["spring"].__setitem__("preload_n", 100.0), "primary.spring.preload_n"),
    (lambda d: d["drive"].__setitem__("primary_radius_max_m", 0.01), "drive.primary_radius_max_m"),
    (lambda d: d["secondary"]["helix"].__setitem__("angle_reference", "lead"), "secondary.helix.angle_reference"),
    (lambda d: d["secondary"]["spring"].__setitem__("rate_n_per_m", -1.0), "secondary.spring.rate_n_per_m"),
    (lambda d: d.pop("secondary"), "secondary"),
    (lambda d: d["primary"].__setitem__("actuator", "hydraulic"), "primary.actuator"),
])
def test_bad_input_names_the_field(mutate, field):
    d = _raw()
    mutate(d)
    with pytest.raises(ConfigError) as exc:
        tune_from_dict(d, "x.toml")
    assert exc.value.field == field
    assert exc.value.path == "x.toml"


def test_load_errors_for_file_problems(tmp_path):
    with pytest.raises(ConfigError):
        load_tune(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = [unclosed")
    with pytest.raises(ConfigError) as exc:
        load_tune(bad)
    assert exc.value.field == "<toml>"


def test_linear_ramp_shorthand_and_roller_track():
    d = _raw()
    fw = d["primary"]["flyweights"]
    for k in ("sheave_travel_m", "radius_m"):
        fw.pop(k)
    fw["ramp_radius_start_m"] = 0.04
    fw["ramp_radial_per_axial"] = 0.5
    t = tune_from_dict(d)
    assert t.flyweights.radius_m[0] == 0.04 and len(t.flyweights.radius_m) == 2
    d = _raw()
    d["primary"] = {"actuator": "roller_track", "spring": d["primary"]["spring"],
                    "roller_track": {"total_mass_kg": 0.0426, "roller_radius_min_m": 0.03,
                                     "track_centre_radius_m": 0.02, "track_centre_axial_m": -0.0229129,
                                     "track_radius_m": 0.025, "fixed_ramp_angle_deg": 60.0}}
    t = tune_from_dict(d)
    assert t.primary_actuator == "roller_track"
    d["primary"]["roller_track"]["track_radius_m"] = 0.03
    with pytest.raises(ConfigError) as exc:
        tune_from_dict(d)
    assert exc.value.field == "primary.roller_track.track_radius_m"
