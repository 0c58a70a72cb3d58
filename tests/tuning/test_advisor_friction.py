"""The advisor's friction terms (dyno.tuning.advisor_model): what the frictionless relations leave out, in the
direction the physics says -- a grippier flank engages the belt sooner, the ramps' friction on the up-shift acts
as a lighter flyweight set -- and nothing else moves."""

from __future__ import annotations

import pytest

from dyno.tuning.advisor_model import THRUST_NOMINAL, predict_figure
from dyno.tuning.tune import load_tune

pytestmark = pytest.mark.quick

STOCK = load_tune("calibration/tunes/cvtech-stock.toml")
LOAD, LOW = 0.6, 3.0
A, C, M, H = THRUST_NOMINAL


def test_flank_friction_lowers_the_engagement_and_leaves_the_shift_out():
    base = predict_figure(STOCK, "engagement", LOAD, LOW, thrust=(A, C, 0.0, H))
    grippy = predict_figure(STOCK, "engagement", LOAD, LOW, thrust=(A, C, 0.2, H))
    slippy = predict_figure(STOCK, "engagement", LOAD, LOW, thrust=(A, C, -0.2, H))
    assert slippy > base > grippy  # the clamp needed falls as 1/mu, and the flyweights' force rises with n^2
    for m in (-0.2, 0.2):
        assert predict_figure(STOCK, "shift_out", LOAD, LOW, thrust=(A, C, m, H)) == pytest.approx(
            predict_figure(STOCK, "shift_out", LOAD, LOW, thrust=(A, C, 0.0, H)), abs=1e-9)


@pytest.mark.parametrize("figure", ["engagement", "shift_out"])
def test_ramp_friction_is_a_lighter_flyweight_set_on_the_up_shift(figure):
    h = 0.06
    with_friction = predict_figure(STOCK, figure, LOAD, LOW, thrust=(A, C, M, h))
    lighter = STOCK.with_changes(**{"flyweights.mass_each_kg": STOCK.flyweights.mass_each_kg * (1.0 - h)})
    assert with_friction == pytest.approx(predict_figure(lighter, figure, LOAD, LOW, thrust=(A, C, M, 0.0)), rel=1e-9)
    frictionless = predict_figure(STOCK, figure, LOAD, LOW, thrust=(A, C, M, 0.0))
    # F ~ m n^2: a (1 - h) force needs n / sqrt(1 - h) -- about 3 % more rpm at h = 6 %
    assert with_friction / frictionless == pytest.approx((1.0 - h) ** -0.5, rel=0.02)
