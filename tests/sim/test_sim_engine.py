"""Engine: map at full throttle, idle, clamping, kill, stall-free start, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dyno.errors import ConfigError
from dyno.sim.engine import EngineMap, load_engine_map
from dyno.sim.physics import RigModel
from dyno.sim.rig_params import RigParams, resolve_map_path

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def test_engine_map_file_is_representative_and_shaped():
    path = resolve_map_path(RigParams().engine_map_path)
    head = path.read_text().lower()
    assert "representative" in head and "not a measurement" in head
    rpm, torque = load_engine_map(path)
    assert rpm[0] <= 1500 and rpm[-1] >= 3850
    peak = int(np.argmax(torque))
    assert 18.0 <= torque[peak] <= 19.0 and 2400 <= rpm[peak] <= 2800
    assert torque[-1] == 0.0 and 3750 <= rpm[-1] <= 3900


def test_engine_map_clamps_outside_its_range():
    m = EngineMap.from_csv(resolve_map_path(RigParams().engine_map_path))
    assert m.torque_nm_at(500.0) == pytest.approx(m.torque_nm_at(m.rpm_min))
    assert m.torque_nm_at(6000.0) == pytest.approx(m.torque_nm_at(m.rpm_max))
    grid = np.linspace(m.rpm_min, m.rpm_max, 997)
    fast = np.array([m.torque_nm_at(n) for n in grid])
    assert np.max(np.abs(fast - m.torque_exact_nm(grid))) < 1e-4


@pytest.mark.parametrize("text, field", [
    ("rpm,torque_nm\n1500,15\n1400,16\n", "line 3, field rpm"),
    ("rpm,torque_nm\n1500,abc\n", "line 2"),
    ("rpm,torque_nm\n1500,15\n", "rows"),
])
def test_malformed_engine_map_names_file_and_field(tmp_path, text, field):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(ConfigError) as ei:
        RigModel(RigParams(engine_map_path=str(p)))
    assert str(p) in str(ei.value) and field in str(ei.value)


def test_idle_holds_about_1800_rpm_with_the_belt_disengaged(make_driver):
    d = make_driver(seed=1)
    d.model.start_engine()
    _, truths = d.run(4.0)
    tr = truths[-1]
    assert tr.engine_running
    assert 1750 < tr.rpm_primary < 1850
    assert tr.rpm_secondary == 0.0


@pytest.mark.parametrize("actuator_s", [0.0, 2.0, 4.0])
def test_full_throttle_mean_engine_torque_equals_the_map(make_driver, actuator_s):
    d = make_driver(seed=2)
    d.start_full_throttle()
    if actuator_s:
        d.brake_step(actuator_s, 6.0)
    _, truths = d.run(2.0)
    engine_map = d.model.engine_map
    for tr in truths[-20:]:
        assert tr.torque_engine_nm == pytest.approx(float(engine_map.torque_exact_nm(tr.rpm_primary)), abs=2e-3)
    # ... and in steady state it is what drives the belt
    tr = truths[-1]
    assert tr.torque_primary_nm == pytest.approx(tr.torque_engine_nm, abs=0.1)   # rotor fade: slow drift


def test_kill_stops_the_engine_and_start_needs_enable(make_driver):
    d = make_driver(seed=3)
    d.start_full_throttle()
    d.brake_step(1.0, 2.0)
    d.model.engine_enabled = False
    _, truths = d.run(0.02)
    assert not truths[-1].engine_running
    assert truths[-1].torque_engine_nm < 0.0
    _, truths = d.run(15.0)
    assert truths[-1].rpm_primary == 0.0 and truths[-1].rpm_secondary == 0.0
    # A killed engine only slows down (sampled every 0.5 s: while the belt still
    # grips, a down-shift can hand the engine a little of the secondary's inertia).
    rpm = [t.rpm_primary for t in truths][::75]
    assert all(b <= a + 1e-9 for a, b in zip(rpm, rpm[1:])), "a killed engine only slows down"
    d.model.start_engine()          # kill relay still open: no start
    _, truths = d.run(1.0)
    assert not truths[-1].engine_running and truths[-1].rpm_primary == 0.0
    d.model.engine_enabled = True
    d.model.throttle_frac = 0.0
    d.model.start_engine()
    _, truths = d.run(4.0)
    assert truths[-1].engine_running and 1750 < truths[-1].rpm_primary < 1850


def test_same_seed_same_everything_other_seed_other_noise():
    def record(seed):
        m = RigModel(seed=seed)
        m.start_engine()
        out = []
        for i in range(1500):
            if i == 300:
                m.throttle_frac = 1.0
            m.actuator_dir = 1 if 900 <= i < 960 else 0
            out.extend((e.channel, e.t_s, e.code, e.status) for e in m.step(1 / 150))
        return out, m.truth()

    a, ta = record(7)
    b, tb = record(7)
    c, _ = record(8)
    assert a == b and ta == tb
    assert [x for x in a if x[0] == "adc"] != [x for x in c if x[0] == "adc"]
    assert not math.isnan(ta.efficiency)


def test_events_do_not_depend_on_how_the_host_slices_time():
    def record(dts):
        m = RigModel(seed=5)
        m.throttle_frac = 1.0
        m.actuator_dir = 1
        m.start_engine()
        out = []
        for dt in dts:
            out.extend((e.channel, e.t_s, e.code, e.status) for e in m.step(dt))
        return out, m.t_s, m.truth().rpm_secondary

    rng = np.random.default_rng(0)
    regular = [1 / 150] * 900                                   # 6 s at the host's pace
    irregular = list(rng.uniform(0.0, 0.02, 500))              # ~5 s, incl. zero-length steps
    irregular[::50] = [0.0] * len(irregular[::50])
    irregular.append(6.0 - sum(irregular))
    a, ta, wa = record(regular)
    b, tb, wb = record(irregular)
    assert ta == pytest.approx(tb) and wa == pytest.approx(wb, rel=1e-4)
    n = min(len(a), len(b)) - 5        # the ends may differ by the last float ulp of t
    assert len(a) > 1000 and a[:n] == b[:n]
