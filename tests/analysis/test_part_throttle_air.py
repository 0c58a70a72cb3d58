"""A part-throttle curve at the day's air (dyno.analysis.part_throttle_air): the fuelled torque scales, the
friction does not -- judged against the simulated engine on days far from J1349's reference, at the light-load
cells where dividing the whole curve by the factor was > 5 % off."""

import numpy as np
import pytest

from dyno.analysis.air import dry_air_pressure_kpa
from dyno.analysis.engine_map import load_engine_map
from dyno.analysis.part_throttle_air import FRICTION_ESTIMATE_NM, friction_u95_nm, part_throttle_at_ambient
from dyno.sim.physics import RigModel
from dyno.sim.rig_params import RigParams

pytestmark = pytest.mark.quick

PART_MAP = "calibration/engine_maps/baja-10hp-representative-part-throttle.csv"
DAYS = [(40.0, 88.0, 30.0), (-5.0, 103.0, 50.0), (30.0, 95.0, 40.0)]  # hot and high, cold and dense, warm


def _light_load_cells(day):
    """(throttle, rpm, the sim engine's torque, the host's new torque, its friction term, the old torque)."""
    host = load_engine_map(PART_MAP)
    sim = RigModel(RigParams(ideal=True, ambient_day=day, belt_efficiency_source="loss_model")).engine
    at_day = host.at_ambient(day[0], dry_air_pressure_kpa(day[1], day[0], day[2]))
    cells = []
    for u in host.throttles[:-1]:
        curve, std = at_day.at_throttle(u), host.at_throttle(u)
        for n in np.linspace(curve.rpm_min, curve.rpm_max, 200):
            true = sim.torque_nm(n, u, True)
            if 1.0 < true < 0.5 * sim.torque_nm(n, 1.0, True):  # light load: under half the full torque
                cells.append((u, n, true, float(curve.torque_nm(n)), friction_u95_nm(curve, n),
                              float(std.torque_nm(n)) / at_day.j1349_factor))
    assert len(cells) >= 20
    return cells


@pytest.mark.parametrize("day", DAYS)
def test_light_load_cells_land_on_the_sim_engine_within_the_stated_friction_term(day):
    cells = _light_load_cells(day)
    old_worst = max(abs(old - true) / true for _, _, true, _, _, old in cells)
    for u, n, true, new, fr95, _ in cells:
        assert abs(new - true) <= fr95 + 0.01 * true, (u, n, true, new, fr95)
    new_worst = max(abs(new - true) / true for _, _, true, new, _, _ in cells)
    print(f"light-load cells: worst {new_worst:.3f} (was {old_worst:.3f} dividing the whole curve)")
    assert new_worst < 0.05 < old_worst and new_worst < old_worst / 2  # the whole-curve division was > 5 % off


def test_full_throttle_and_the_reference_day_are_unchanged():
    full = np.array([18.0, 20.0, 19.0])
    t, fr95 = part_throttle_at_ambient([2000, 3000, 3600], full, full, 1.2)
    assert np.allclose(t, full / 1.2) and np.allclose(fr95, 0.0)  # full throttle: J1349's own correction
    part = np.array([5.0, 3.0, 1.0])
    t, fr95 = part_throttle_at_ambient([2000, 3000, 3600], part, full, 1.0)
    assert np.allclose(t, part) and np.allclose(fr95, 0.0)  # the reference day: nothing to correct
    t, _ = part_throttle_at_ambient([2000], [5.0], [18.0], 1.2)
    # the fuelled part (5 + friction) scales by the full curve's own ratio, the friction is subtracted whole
    g = (18.0 / 1.2 + FRICTION_ESTIMATE_NM) / (18.0 + FRICTION_ESTIMATE_NM)
    assert t[0] == pytest.approx((5.0 + FRICTION_ESTIMATE_NM) * g - FRICTION_ESTIMATE_NM)
    assert t[0] < 5.0 / 1.2  # less than the whole-curve division takes off a hot day: the friction stays
