"""The engine map's stated uncertainty lives with the map file, and a run says what each u95 term assumes."""

from __future__ import annotations

import math
import types
from pathlib import Path

import pytest

from dyno.analysis import u95_terms
from dyno.analysis.engine_map import load_engine_map
from dyno.analysis.measured_map import write_map
from dyno.resources import DEFAULT_CALIBRATION
from dyno.session.root import RunSpec, systematic_terms
from dyno.errors import ConfigError

pytestmark = pytest.mark.quick

REPO = Path(__file__).resolve().parents[2]
SHIPPED = REPO / "calibration" / "engine_maps" / "baja-10hp-representative.csv"
PLAIN = "rpm,torque_nm\n2000,17\n3000,18\n"


def _rig(default_rel=0.05):
    return types.SimpleNamespace(uncertainty=types.SimpleNamespace(engine_map_rel=default_rel))


def _terms(engine_map, default_rel=0.05):
    from dyno.analysis.calibration_history import latest, load_history

    cal = latest(load_history(DEFAULT_CALIBRATION))
    return systematic_terms(RunSpec(), _rig(default_rel), cal, engine_map)


def test_shipped_maps_say_they_are_not_measured_and_state_the_evidence():
    """The representative maps are no engine's: they say so, and state at least the spread real engines show
    about maps (the 2019 rig's engine ~9 % under its own, a used engine's shape 3.9 % RMS: 9.8 %)."""
    assert u95_terms.UNMEASURED_MAP_U_REL == pytest.approx(math.hypot(0.09, 0.039))
    for name in ("baja-10hp-representative.csv", "baja-10hp-representative-part-throttle.csv"):
        m = load_engine_map(REPO / "calibration" / "engine_maps" / name)
        assert m.measured_on_this_engine is False and not u95_terms.map_measured(m)
        assert m.stated_u_rel == 0.10 >= u95_terms.UNMEASURED_MAP_U_REL and "representative" in m.stated_u_basis
        assert all(c.stated_u_rel == 0.10 and c.measured_on_this_engine is False for c in m.part_throttle.values())
        day = m.at_ambient(35.0, 90.0)  # the day's map keeps both
        assert day.stated_u_rel == 0.10 and day.measured_on_this_engine is False
        assert m.metadata()["stated_u_rel"] == 0.10 and m.metadata()["measured_on_this_engine"] is False


def test_a_map_stating_none_takes_the_rig_files_default_and_says_so(tmp_path):
    (tmp_path / "m.csv").write_text(PLAIN)
    m = load_engine_map(tmp_path / "m.csv")
    assert m.stated_u_rel is None and m.measured_on_this_engine is None
    unc = _terms(m, default_rel=0.12)
    assert unc["engine_map_rel"] == 0.12
    emap = next(t for t in unc["u95_terms"] if t["term"] == "engine_map")
    assert emap["u_rel"] == 0.12 and "rig.toml [uncertainty] engine_map_rel" in emap["basis"]
    assert emap["measured"] is False


@pytest.mark.parametrize("said", ["", "# measured_on_this_engine = no\n"])
def test_a_map_not_measured_on_this_engine_never_states_less_than_real_engines_spread(tmp_path, said):
    (tmp_path / "m.csv").write_text(f"# stated_u_rel = 0.03 | a maker's brochure\n{said}{PLAIN}")
    unc = _terms(load_engine_map(tmp_path / "m.csv"), default_rel=0.01)
    assert unc["engine_map_rel"] == pytest.approx(u95_terms.UNMEASURED_MAP_U_REL)
    emap = next(t for t in unc["u95_terms"] if t["term"] == "engine_map")
    assert "raised from 3 %" in emap["basis"] and "not measured on this engine" in emap["basis"]


def test_a_map_measured_on_this_engine_keeps_its_statement(tmp_path):
    (tmp_path / "m.csv").write_text(f"# stated_u_rel = 0.03 | dyno'd\n# measured_on_this_engine = yes\n{PLAIN}")
    unc = _terms(load_engine_map(tmp_path / "m.csv"))
    assert unc["engine_map_rel"] == 0.03 and "engine_wear_max_frac" not in unc  # its own engine: no wear term
    assert next(t for t in unc["u95_terms"] if t["term"] == "engine_map")["measured"] is True


def test_the_maps_statement_is_the_runs_map_term():
    unc = _terms(load_engine_map(SHIPPED), default_rel=0.2)  # the map's own 10 %, not the rig file's 20 %
    assert unc["engine_map_rel"] == 0.10
    names = [t["term"] for t in unc["u95_terms"]]
    assert names == ["statistical", "calibration", "engine_map", "engine_wear"]  # (one-sided: not measured on it)
    assert unc["engine_wear_max_frac"] == u95_terms.ENGINE_WEAR_MAX_FRAC == 0.14
    cal = next(t for t in unc["u95_terms"] if t["term"] == "calibration")
    assert cal["u_rel"] == pytest.approx(unc["torque_calibration_rel"]) and "4 entries" in cal["basis"]
    assert "stated in the map file" in unc["u95_terms"][2]["basis"]
    lines = u95_terms.describe(unc["u95_terms"] + [u95_terms.air_term(0.001, "sensor")])
    assert lines[2].startswith("engine_map: 10.00 %") and "BME280" in lines[4]


def test_the_advice_to_measure_the_engine_follows_the_dominant_term():
    terms = [{"term": "engine_map", "u_rel": 0.1, "basis": "", "measured": False}]
    mapped = [{"efficiency_u95": 0.15, "efficiency_u95_terms": {"statistical": 0.01, "engine_map": 0.17}}]
    measured_wide = [{"efficiency_u95": 0.05, "efficiency_u95_terms": {"statistical": 0.01, "calibration": 0.04,
                                                                       "engine_map": 0.02}}]
    assert "measure the engine" in u95_terms.advice(terms, mapped)
    assert u95_terms.advice(terms, measured_wide) == ""  # the map is not what limits it
    assert u95_terms.advice([{**terms[0], "measured": True}], mapped) == ""


@pytest.mark.parametrize("line", ["# measured_on_this_engine = maybe", "# measured_on_this_engine ="])
def test_a_bad_measured_line_names_the_file_line_and_field(tmp_path, line):
    (tmp_path / "m.csv").write_text(f"# a map\n{line}\n{PLAIN}")
    with pytest.raises(ConfigError) as e:
        load_engine_map(tmp_path / "m.csv")
    assert "m.csv" in str(e.value) and "line 2" in str(e.value) and "measured_on_this_engine" in str(e.value)


@pytest.mark.parametrize("line", ["# stated_u_rel = 0 | none", "# stated_u_rel = five", "# stated_u_rel 0.05",
                                  "# stated_u_rel = 1.5 | more than the torque"])
def test_a_bad_statement_names_the_file_line_and_field(tmp_path, line):
    (tmp_path / "m.csv").write_text(f"# a map\n{line}\n{PLAIN}")
    with pytest.raises(ConfigError) as e:
        load_engine_map(tmp_path / "m.csv")
    assert "m.csv" in str(e.value) and "line 2" in str(e.value) and "stated_u_rel" in str(e.value)


def test_a_measured_map_carries_its_measurements_uncertainty(tmp_path):
    curve = [{"rpm": 2500.0, "torque_nm": 16.0, "torque_u95_nm": 0.48, "n_points": 3},
             {"rpm": 3000.0, "torque_nm": 15.0, "torque_u95_nm": 0.60, "n_points": 2}]
    write_map(curve, tmp_path / "measured.csv")
    m = load_engine_map(tmp_path / "measured.csv")
    assert m.stated_u_rel == pytest.approx(math.ceil(0.60 / 2 / 15.0 * 1000) / 1000)  # the worst row's: 0.020
    assert "input torque channel" in m.stated_u_basis and m.measured_on_this_engine is True
    assert _terms(m)["engine_map_rel"] == pytest.approx(0.02)  # measured on this engine: not raised
