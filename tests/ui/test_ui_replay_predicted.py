import pytest
"""The replay viewer's predicted shift curve comes from the tune stored with the run."""

import shutil
from pathlib import Path

from dyno.ui.replay_model import predicted_shift_series

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

REPO = Path(__file__).resolve().parents[2]


def _fake_run(tmp_path, with_tune=True):
    d = tmp_path / "run"
    d.mkdir()
    shutil.copy(REPO / "calibration/engine_maps/baja-10hp-representative.csv", d / "engine_map.csv")
    if with_tune:
        shutil.copy(REPO / "calibration/tunes/cvtech-stock.toml", d / "tune.toml")
    return d


def test_predicted_curve_from_the_runs_tune(tmp_path):
    x, y = predicted_shift_series(_fake_run(tmp_path))
    assert len(x) >= 20
    # along the curve the secondary speeds up as the CVT shifts out, engine rpm within the map
    assert x[-1] > x[0]
    assert all(1000 < n < 4000 for n in y)


def test_no_tune_no_prediction(tmp_path):
    assert predicted_shift_series(_fake_run(tmp_path, with_tune=False)) is None
