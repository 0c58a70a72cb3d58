"""Two trips ahead (dyno.tuning.advisor_plan): the adjustments are the same physical parts re-set, and
the look-ahead credits a tune whose misses an adjustment can trim -- and only those."""

from __future__ import annotations

import numpy as np
import pytest

from dyno.tuning.advisor import tolerance_lookup
from dyno.tuning.advisor_model import Calibration, predict_figure
from dyno.tuning.advisor_plan import adjustments, figure_covariance, two_trip_probability
from dyno.tuning.parts import load_catalogue, part_identity
from dyno.tuning.tune import load_tune

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

CAT = load_catalogue("calibration/parts")
STOCK = load_tune("calibration/tunes/cvtech-stock.toml")
KINDS = ("flyweights", "primary_spring", "secondary_spring", "helix")
LOAD, LOW = 0.6, 3.0


def _no_runs() -> Calibration:
    return Calibration([], np.zeros(0), np.zeros((0, 0)), 1.0, 0)


def test_adjustments_are_the_same_parts_re_set():
    adj = adjustments(STOCK, CAT)
    washers = {round(t.flyweights.washer_mass_each_kg, 3) for t in adj}
    positions = {t.secondary_spring.torsion_preload_nm for t in adj}
    assert washers == {0.0} | {round(0.004 * k, 3) for k in range(1, 14)} and positions == {0.6, 1.0, 1.4}
    assert len(adj) == 13 + 2 + 13 * 2
    for t in adj:
        assert all(part_identity(t, k) == part_identity(STOCK, k) for k in KINDS)
        assert any(part_identity(t, k, with_settings=True) != part_identity(STOCK, k, with_settings=True)
                   for k in KINDS)
    heavy = load_tune("calibration/tunes/heavy-flyweights.toml")  # a body without washer sets: positions only
    assert {t.flyweights.mass_each_kg for t in adjustments(heavy, CAT)} == {heavy.flyweights.mass_each_kg}


def test_two_trips_credit_only_what_an_adjustment_can_trim():
    cal, tol_of = _no_runs(), tolerance_lookup(CAT, [STOCK])
    figs = ("engagement", "shift_out")
    mean, cov = figure_covariance(cal, STOCK, figs, LOAD, LOW, tol_of)
    u = np.sqrt(np.diag(cov))
    assert mean == pytest.approx([predict_figure(STOCK, f, LOAD, LOW) for f in figs], abs=1e-6)
    assert 40.0 < u[0] < 120.0  # a flyweight body and a spring at their +-10 % priors
    # a target an adjustment reaches (the stock body with 20 g of washers on): one trip is a gamble with the
    # parts' tolerances; two trips -- measure, then trim with washers -- fail only where the parts came out
    # so heavy that the target needs washers off a body that has none, or so light that the rig's
    # secondary check aborts the run (measured on the first-estimate stock tune p1 0.06, p2 0.41; on the
    # re-estimate, engaging lower, 0.30 / 0.71)
    washed = STOCK.with_changes(**{"flyweights.mass_each_kg": 0.248, "flyweights.washer_mass_each_kg": 0.020})
    near = {f: predict_figure(washed, f, LOAD, LOW) for f in figs}
    p2 = two_trip_probability(cal, STOCK, CAT, near, 50.0, LOAD, LOW, tol_of, mean, cov)
    p1 = float(np.prod([_p(mean[i], u[i], near[f]) for i, f in enumerate(figs)]))
    assert p1 < 0.5 and p2 > p1 + 0.3
    # a target no washer or position reaches (engagement 250 rpm higher: a stiffer spring's job): no credit
    far = {"engagement": mean[0] + 250.0, "shift_out": mean[1] + 250.0}
    assert two_trip_probability(cal, STOCK, CAT, far, 50.0, LOAD, LOW, tol_of, mean, cov) < 0.05


def _p(m, u, t, tol=50.0):
    from math import erf, sqrt

    return 0.5 * (erf((t + tol - m) / (u * sqrt(2))) - erf((t - tol - m) / (u * sqrt(2))))


@pytest.mark.parametrize("f_s, t_p, decay", [(500.0, 1e-9, 1.0), (500.0, 2.0, 1.0), (1e6, 1e-3, 3.0), (80.0, 6.0, 2.5)])
def test_thrust_ratio_balance_solves_at_any_scale(f_s, t_p, decay):
    """The shift-out balance kappa(F) F = F_s: a root at every scale (tiny torques once made brentq's
    bracket lose its sign to rounding)."""
    import math

    from dyno.tuning.advisor_model import primary_force_for_secondary_n

    r_p, kappa0 = 0.032, 1.39
    f = primary_force_for_secondary_n(f_s, t_p, r_p, kappa0, decay)
    assert f * kappa0 * math.exp(-decay * t_p / (r_p * f)) == pytest.approx(f_s, rel=1e-6)
