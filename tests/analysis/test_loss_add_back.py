"""Adding back a driven-side loss to a point's efficiency, uncertainty propagated."""

import math

import pytest

from dyno.analysis.efficiency import add_back_loss

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def test_add_back_loss_propagates_both_uncertainties():
    eta, ci = add_back_loss(0.85, 0.008, 5000.0, 3000.0, 0.12, 0.05)
    w = 3000 * math.pi / 30
    assert eta == pytest.approx(0.85 + 0.12 * w / 5000)
    assert ci == pytest.approx(math.hypot(0.008, 0.05 * w / 5000))
