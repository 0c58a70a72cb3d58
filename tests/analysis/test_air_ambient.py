"""The run's air (dyno.analysis.air): parsing what an operator types, J1349 by the physics, and the
uncertainty each way of knowing the day leaves."""

from __future__ import annotations

import math

import pytest

from dyno.analysis.air import (PLAUSIBLE_PRESSURE_KPA, PLAUSIBLE_TEMP_C, Ambient, j1349_correction_factor,
                               j1349_factor_of, known_air_rel_u, parse_ambient, uncorrected_air_rel_u)

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def test_hot_high_day_factor_follows_density_and_friction():
    # 35 C, 90 kPa station, 20 %RH: dry air 89.88 kPa; CF = 1.176 (99/p_d) sqrt(308/298) - 0.176
    p_d = 90.0 - 0.2 * 5.6290  # Buck: e_s(35 C) = 5.629 kPa
    want = 1.176 * (99.0 / p_d) * math.sqrt(308.0 / 298.0) - 0.176
    assert j1349_factor_of(35.0, 90.0, 20.0) == pytest.approx(want, rel=1e-4)
    assert 1.15 < want < 1.16
    assert j1349_factor_of(25.0, 99.0, 0.0) == pytest.approx(1.0, abs=1e-12)  # the reference day


@pytest.mark.parametrize("text, bad", [("35", "TEMP_C,PRESSURE_KPA"), ("35,900", "PRESSURE_KPA 900"),
                                       ("99,90", "TEMP_C 99"), ("35,90,120", "RH_PCT 120"), ("a,b", "expected"),
                                       ("35,90,20,1", "expected"), ("nan,90", "expected")])
def test_bad_ambient_names_what_is_expected(text, bad):
    with pytest.raises(ValueError, match=bad) as e:
        parse_ambient(text)
    assert str(e.value).startswith("--ambient: ")


def test_ambient_without_humidity_is_corrected_and_wider():
    a = parse_ambient("30,95")
    assert a.corrected and a.rh_pct is None and a.source == "given"
    assert a.air_rel_u() > known_air_rel_u(30.0, 95.0, 40.0)  # an unknown humidity costs something
    d = a.to_dict()
    assert set(d) == {"temp_c", "pressure_kpa", "rh_pct", "source", "j1349_factor"}


def test_uncorrected_factor_is_its_distribution_over_a_uniform_day():
    """Uncorrected, the truth is the figure times CF of the unknown day.  The host's quantiles of CF (a grid
    over the day's box) against an independent Monte-Carlo draw of uniform days; the range is the issue's
    0.866..1.406 at the box's corners, and the symmetric summary is half the 95 % range (k = 2)."""
    import numpy as np

    from dyno.analysis.air import PLAUSIBLE_VAPOUR_KPA, saturation_vapour_pressure_kpa, uncorrected_factors

    rng = np.random.default_rng(39)
    t = rng.uniform(*PLAUSIBLE_TEMP_C, 20000)
    p = rng.uniform(*PLAUSIBLE_PRESSURE_KPA, 20000)
    es = np.array([min(PLAUSIBLE_VAPOUR_KPA[1], saturation_vapour_pressure_kpa(x)) for x in t])
    cf = np.array([j1349_correction_factor(a, b - c) for a, b, c in zip(t, p, rng.uniform(0, 1, 20000) * es)])
    q = np.asarray(uncorrected_factors())
    for prob in (0.025, 0.5, 0.975):
        assert np.quantile(q, prob) == pytest.approx(np.quantile(cf, prob), abs=0.006)
    corners = [j1349_correction_factor(a, b - min(e, saturation_vapour_pressure_kpa(a)))
               for a in PLAUSIBLE_TEMP_C for b in PLAUSIBLE_PRESSURE_KPA for e in PLAUSIBLE_VAPOUR_KPA]
    assert min(corners) == pytest.approx(0.866, abs=0.002) and max(corners) == pytest.approx(1.406, abs=0.002)
    assert min(corners) <= q[0] and q[-1] <= max(corners)
    lo, hi = np.quantile(q, (0.025, 0.975))
    assert 2.0 * uncorrected_air_rel_u() == pytest.approx((hi - lo) / 2.0, abs=0.005)
    assert Ambient().j1349_factor is None and not Ambient().corrected
    assert Ambient().air_rel_u() == uncorrected_air_rel_u()
    # a known site narrows the pressure, and so the factor's spread
    assert uncorrected_air_rel_u(0.0) < 0.6 * uncorrected_air_rel_u()


def test_known_air_term_matches_the_sensitivity():
    """Numerically: the relative change of CF for +-1 C, taken as rectangular, dominates at 25 C."""
    u = known_air_rel_u(25.0, 99.0, 0.0)
    cf = j1349_correction_factor
    dt = (cf(26.0, 99.0) - cf(24.0, 99.0)) / 2.0 / math.sqrt(3.0)
    assert dt < u < 2.0 * dt


def test_every_face_says_what_was_done_with_the_air():
    from dyno.cli.run_cmd import air_line
    from dyno.report.html import air_text
    from dyno.ui.live_model import last_point_text

    none, given = Ambient().to_dict(), parse_ambient("35,90,20").to_dict()
    assert "uncorrected" in air_line(none) and "uncorrected" in air_text(none)
    assert "1.1558" in air_line(given) and "1.1558" in air_text(given)
    assert "not recorded" in air_text({})  # a run from before the air was logged
    pt = {"efficiency": 0.85, "efficiency_ci95": 0.006, "efficiency_u95": 0.09}
    assert last_point_text([pt]) == ("U95 ±9.0 pp", "")
    pt["efficiency_interval95"] = [0.77, 0.951]
    assert last_point_text([pt]) == ("U95 ±9.0 pp", "77.0…95.1 %")  # (the live screen's interval95 row)
    assert last_point_text([]) == ("", "")
