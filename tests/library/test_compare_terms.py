"""What cancels in a two-run efficiency difference (dyno.library.compare_terms), on made-up runs."""

import math

import numpy as np
import pytest

from dyno.analysis.air import Ambient, known_air_rel_u, uncorrected_air_rel_u
from dyno.library.compare import ATMOSPHERE_NOTE, compare
from dyno.library.compare_terms import MAP_DECORRELATION_RPM, difference_terms, run_systematics

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

SENSED = {"temp_c": 30.0, "pressure_kpa": 95.0, "rh_pct": 40.0, "source": "sensor", "j1349_factor": 1.05}
NONE = {"temp_c": None, "pressure_kpa": None, "rh_pct": None, "source": "none", "j1349_factor": None}


def _run(ambient=SENSED, cal=("2019-04-18", 108.188), sha="m" * 64, cal_rel=0.0157, map_rel=0.05, uncertainty=True):
    amb = Ambient.from_dict(ambient)
    meta = {"ambient": ambient}
    if uncertainty:
        meta["uncertainty"] = {"torque_calibration_rel": cal_rel, "engine_map_rel": map_rel,
                               "air_rel": amb.air_rel_u()}
    return {"row": {"calibration_date": cal[0], "calibration_slope_counts_per_nm": cal[1], "engine_map_sha256": sha},
            "meta": meta}


def _terms(a, b, eff_a=0.90, eff_b=0.88, n_a=3000.0, n_b=2800.0, sem_d=0.002):
    arr = lambda v: np.array([v])  # noqa: E731
    return difference_terms(arr(eff_a), arr(eff_b), arr(n_a), arr(n_b), arr(sem_d), arr(0.0), arr(0.0),
                            run_systematics(a), run_systematics(b))


def test_one_rig_calibration_and_map_leave_residuals_far_below_the_full_terms():
    res = _terms(_run(), _run())
    t = res["terms"]
    assert t["calibration"]["status"] == "residual" and t["engine_map"]["status"] == "residual"
    # slope common: only |d| u_cal is left (no tare here)
    assert t["calibration"]["u95"][0] == pytest.approx(2 * 0.02 * 0.0157)
    # map: its change over 200 rpm (assumed sd·√2·200/1000) and |d| u_map
    shift = 0.89 * 0.05 * math.sqrt(2) * 200 / MAP_DECORRELATION_RPM
    assert t["engine_map"]["u95"][0] == pytest.approx(2 * math.hypot(shift, 0.02 * 0.05))
    full = _terms(_run(), _run(cal=("2020-01-01", 110.0), sha="x" * 64))["terms"]
    assert full["calibration"]["status"] == full["engine_map"]["status"] == "not cancelled"
    assert full["engine_map"]["u95"][0] == pytest.approx(2 * math.hypot(0.9 * 0.05, 0.88 * 0.05))
    assert t["engine_map"]["u95"][0] < 0.25 * full["engine_map"]["u95"][0]
    assert t["calibration"]["u95"][0] < 0.05 * full["calibration"]["u95"][0]
    unknown = _terms(_run(cal=(None, None), sha=None), _run(cal=(None, None), sha=None))["terms"]
    assert unknown["calibration"]["status"] == unknown["engine_map"]["status"] == "not cancelled"
    assert "cannot be told to be the same" in unknown["calibration"]["reason"]


def test_the_map_residual_grows_with_the_engine_speed_gap_and_saturates():
    u = [_terms(_run(), _run(), eff_a=0.9, eff_b=0.9, n_a=3000.0, n_b=3000.0 + dn)["terms"]["engine_map"]["u95"][0]
         for dn in (0.0, 100.0, 500.0, 1000.0, 2000.0)]
    assert u[0] == 0.0 and u[1] < u[2] < u[3]
    assert u[3] == pytest.approx(u[4]) == pytest.approx(2 * 0.9 * 0.05 * math.sqrt(2))


def test_air_cancels_only_when_both_runs_are_corrected():
    both = _terms(_run(), _run())["terms"]["air"]
    assert both["status"] == "residual"
    u_known = known_air_rel_u(30.0, 95.0, 40.0)
    assert both["u95"][0] == pytest.approx(2 * math.hypot(0.9 * u_known, 0.88 * u_known))
    mixed = _terms(_run(), _run(ambient=NONE))["terms"]["air"]
    assert mixed["status"] == "not cancelled" and "only run A" in mixed["reason"]
    neither = _terms(_run(ambient=NONE), _run(ambient=NONE), eff_a=0.9, eff_b=0.9)["terms"]["air"]
    assert neither["status"] == "not cancelled"
    assert neither["u95"][0] == pytest.approx(2 * 0.9 * uncorrected_air_rel_u() * math.sqrt(2))
    assert neither["u95"][0] > 10 * both["u95"][0]


def test_runs_without_uncertainty_give_the_statistics_alone():
    res = _terms(_run(uncertainty=False), _run(uncertainty=False))
    assert {k: t["status"] for k, t in res["terms"].items()} == {
        "statistical": "not cancelled", "calibration": "unknown", "engine_map": "unknown", "air": "unknown"}
    assert res["u95"][0] == pytest.approx(1.959964 * 0.002)


def _points(eff0, rpm_p0, cal95=0.0):
    return [{"valid": True, "rpm_secondary": 2000.0 + 500 * i, "rpm_primary": rpm_p0 + 100 * i,
             "efficiency": eff0 - 0.01 * i, "efficiency_sem": 0.002, "efficiency_sys95_calibration": cal95,
             "torque_secondary_nm": 10.0, "torque_secondary_sem_nm": 0.05, "rpm_secondary_sem": 0.1,
             "power_out_w": 2000.0, "rpm_primary_sem": 1.0} for i in range(5)]


def test_compare_states_u95_and_the_air_of_each_run():
    a = {**_run(), "name": "A", "points": _points(0.90, 3000.0, cal95=2 * 0.9 * 0.03), "tune": None}
    b = {**_run(ambient=NONE), "name": "B", "points": _points(0.88, 2800.0, cal95=2 * 0.88 * 0.03), "tune": None}
    res = compare([a, b], step_rpm=500.0)
    d = res["differences"][0]
    q = d["quantities"]["efficiency"]
    assert len(q["difference_u95"]) == len(res["grid_rpm_secondary"]) == 5
    assert d["terms"]["air"]["status"] == "not cancelled"
    # the tare (calibration term beyond the slope's 1.57 %) is each run's own: it stays in the residual
    tare_a = 0.9 * math.sqrt(0.03 ** 2 - 0.0157 ** 2)
    assert q["difference_u95_terms"]["calibration"][0] > 2 * tare_a
    total = np.sqrt(sum(np.array(v) ** 2 for v in q["difference_u95_terms"].values()))
    assert q["difference_u95"] == pytest.approx(total.tolist())
    assert q["significant_u95"] == [False] * 5
    # torque: the statistics and the two tares (no map, no air): 2·0.0263·10 N·m per run, in quadrature
    tq = d["quantities"]["torque_secondary_nm"]
    assert set(tq["difference_u95_terms"]) == {"statistical", "calibration"}
    tare_nm = 10.0 * math.sqrt(0.03 ** 2 - 0.0157 ** 2)
    assert tq["difference_u95"][0] == pytest.approx(math.hypot(tq["difference_u95_terms"]["statistical"][0],
                                                               2 * math.sqrt(2) * tare_nm), rel=1e-6)
    assert "A: sensor 30.0 °C" in res["atmosphere"] and "B: uncorrected" in res["atmosphere"]
    assert [r["ambient"]["source"] for r in res["runs"]] == ["sensor", "none"]
    old = [{**r, "meta": {}} for r in (a, b)]  # runs from before the air was logged
    assert compare(old, step_rpm=500.0)["atmosphere"] == ATMOSPHERE_NOTE
