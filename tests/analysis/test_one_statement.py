"""Issue 52 item 2: a point makes one 95 % statement, ``efficiency_interval95``; ``efficiency_u95`` is that
interval's half-width (never a second, symmetric statement that adds the one-sided driveline as if it were
symmetric), and every efficiency variant the point gives carries its own ``<variant>_interval95``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dyno.analysis.air import uncorrected_factors
from dyno.analysis.coastdown import driven_loss_keys
from dyno.analysis.systematic import half_width, point_systematic
from dyno.analysis.zero_check import corrected_point_keys

pytestmark = pytest.mark.quick

#: keys named ``efficiency_*`` that are not an efficiency figure (its statistics, terms, reasons, the sim's truth)
_NOT_A_VARIANT = ("_ci95", "_sem", "_u95", "_u95_terms", "_interval95", "_dof", "_reason", "_source", "_true")


def variants(point: dict) -> list[str]:
    """The efficiency figures a point gives: ``efficiency`` and every ``efficiency_<variant>`` that is a number."""
    return [k for k, v in point.items() if (k == "efficiency" or k.startswith("efficiency_"))
            and not k.startswith("efficiency_sys95") and not k.endswith(_NOT_A_VARIANT)
            and isinstance(v, (int, float)) and not isinstance(v, bool)]


@pytest.mark.parametrize("air_known", [True, False])
@pytest.mark.parametrize("eff", [0.62, 0.86, 0.97])  # 0.97: the interval's top is clipped at 100 %
def test_u95_is_the_intervals_half_width_with_the_driveline_one_sided(eff, air_known):
    air_factors = None if air_known else uncorrected_factors()
    s = point_systematic({"efficiency": eff, "efficiency_ci95": 0.008}, 0.016, 0.05, 0.002 if air_known else 0.2,
                         air_factors=air_factors, driveline_max_frac=0.05)
    lo, hi = s["efficiency_interval95"]
    assert s["efficiency_u95"] == pytest.approx((hi - lo) / 2, rel=1e-12)
    assert lo < eff < hi <= 1.0
    # the systematic part alone is stated the same way: half its own interval, narrower than the whole
    no_ci = point_systematic({"efficiency": eff}, 0.016, 0.05, 0.002 if air_known else 0.2,
                             air_factors=air_factors, driveline_max_frac=0.05)
    assert s["efficiency_sys95"] == pytest.approx(no_ci["efficiency_u95"], rel=1e-12)
    assert s["efficiency_sys95"] < s["efficiency_u95"]
    if air_known and hi < 1.0:
        # the driveline only lowers a reading: the interval reaches further up than down, and ±U95 is its
        # half-width, not the driveline's extent added in quadrature as if it could also raise the reading
        assert hi - eff > eff - lo
        t = s["efficiency_u95_terms"]
        as_if_symmetric = math.sqrt(sum(v * v for v in t.values()))
        assert s["efficiency_u95"] < as_if_symmetric
        assert eff - as_if_symmetric < lo  # (the old ±U95's low end lay below the interval's)


def test_the_interval_covers_the_world_it_describes_and_u95_with_it():
    """Readings made from truths the way the interval says (driveline loss uniform 0..L_max, normal terms):
    the interval holds ~95 % of truths; reading ± U95 (its half-width, centred on the reading) is not a
    second claim and is not judged."""
    rng = np.random.default_rng(52)
    n, lmax, sym_rel = 2000, 0.06, 0.05
    truth = rng.uniform(0.6, 0.9, n)
    reading = truth * (1.0 - rng.uniform(0, lmax, n)) * (1.0 + rng.normal(0, sym_rel / 2, n))
    inside = 0
    for t, r in zip(truth, reading):
        s = point_systematic({"efficiency": float(r)}, 0.0, sym_rel / 2, driveline_max_frac=lmax)
        lo, hi = s["efficiency_interval95"]
        assert s["efficiency_u95"] == pytest.approx(half_width([lo, hi]))
        inside += lo <= t <= hi
    assert 0.93 <= inside / n <= 0.97


def test_the_input_paths_u95_is_its_intervals_half_width():
    from dyno.analysis.calibration_history import CalibrationEntry
    from dyno.analysis.input_torque import InputChannel, input_systematic

    ch = InputChannel(CalibrationEntry(date="2026-01-01", slope_counts_per_nm=100.0, intercept_counts=30000.0,
                                       r2=0.9999, n_samples=0), 0.004, 0.0, 0.02)
    p = {"efficiency": 0.84, "efficiency_ci95": 0.006, "torque_input_nm": 17.0, "torque_input_sem_nm": 0.01}
    s = input_systematic(p, 0.004, ch, 0.05)
    lo, hi = s["efficiency_interval95"]
    assert s["efficiency_u95"] == pytest.approx((hi - lo) / 2, rel=1e-12)
    assert hi - 0.84 > 0.84 - lo  # the driveline: one-sided
    assert s["efficiency_sys95"] < s["efficiency_u95"]
    none = input_systematic({"efficiency": math.nan, "torque_input_nm": 17.0}, 0.004, ch, 0.05)
    assert none["efficiency_interval95"] is None and math.isnan(none["efficiency_u95"])  # no statement at all


def _ramp_point(eff=0.82, eff_before_inertia=0.86):
    """A ramp point after its I·alpha correction: ``efficiency_uncorrected`` is the figure before it."""
    return {"efficiency": eff, "efficiency_ci95": 0.009, "efficiency_sem": 0.0045, "efficiency_uncorrected":
            eff_before_inertia, "torque_secondary_nm": 14.0, "rpm_secondary": 3200.0, "power_in_w": 5200.0,
            "host_t_start_s": 10.0, "host_t_end_s": 14.0, "faults": [], "valid": True, "efficiency_true": 0.85}


def _loss():
    return {"loss_fit": {"coefficients": {"a_nm": 0.25, "b_nm_per_rad_s": 0.0, "c_nm_per_rad_s2": 0.0},
                         "covariance": [[1e-4, 0, 0], [0, 0, 0], [0, 0, 0]], "rpm_min": 1000.0, "rpm_max": 6000.0},
            "seen_nm": 0.0}


def test_every_variant_a_point_gives_has_its_own_interval():
    unc = {"air_day": None, "driveline_loss_max_frac": 0.03, "driveline_drag_max_nm": 0.25}
    from dyno.analysis.systematic import interval_basis

    p = _ramp_point()
    p.update(point_systematic(p, 0.016, 0.05, 0.002, **interval_basis(unc, p)))
    p.update(driven_loss_keys(p, _loss(), unc))
    check = {"before": {"torque_nm": 0.0, "t_mid_s": 0.0}, "after": {"torque_nm": 0.2, "t_mid_s": 24.0},
             "drift_nm": 0.2}
    p.update(corrected_point_keys(p, check, unc))
    found = variants(p)
    assert {"efficiency", "efficiency_uncorrected", "efficiency_loss_corrected",
            "efficiency_zero_corrected"} <= set(found), found
    for k in found:
        iv = p.get(f"{k}_interval95" if k != "efficiency" else "efficiency_interval95")
        assert iv is not None, f"{k} has no interval"
        assert 0.0 <= iv[0] < p[k] < iv[1] <= 1.0, (k, p[k], iv)
    # the figure before the I·alpha correction carries the point's terms scaled to it (each is relative)
    lo, hi = p["efficiency_uncorrected_interval95"]
    plo, phi = p["efficiency_interval95"]
    k = 0.86 / 0.82
    assert lo == pytest.approx(plo * k, rel=0.01) and hi == pytest.approx(phi * k, rel=0.01)


def test_the_public_point_keeps_every_variants_interval():
    from dyno.session.summary import public_point

    p = _ramp_point()
    p.update(point_systematic(p, 0.016, 0.05, 0.002, driveline_max_frac=0.04))
    pub = public_point(p)
    for k in variants(pub):
        assert (pub.get(f"{k}_interval95") if k != "efficiency" else pub["efficiency_interval95"]) is not None, k
    assert pub["efficiency_u95"] == pytest.approx(half_width(pub["efficiency_interval95"]))
