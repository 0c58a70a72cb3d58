"""bench/bench_uncertainty.py's judging rule (issue 52 item 3): runs, not points, are the trials; a world fails
only when its coverage is significantly below 0.90 (the Wilson 95 % upper bound under it), or its mean width
is over the path's cap."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import bench_uncertainty as bu  # noqa: E402

pytestmark = pytest.mark.quick


def test_wilson_interval_of_a_proportion():
    lo, hi = bu.wilson95(57, 60)
    assert lo == pytest.approx(0.8628, abs=5e-4) and hi == pytest.approx(0.9829, abs=5e-4)
    assert bu.wilson95(4, 4) == pytest.approx((0.5101, 1.0), abs=5e-4)
    assert bu.wilson95(0, 0)[1] != bu.wilson95(0, 0)[1]  # NaN: nothing judged


def _runs(covered_flags, width=0.2):
    """Runs of three points each; the middle point's interval holds the truth or misses it by its flag."""
    runs = []
    for ok in covered_flags:
        rows = []
        for i in range(3):
            true = 0.8 if (ok or i != 1) else 0.99
            rows.append({"true": true, "known": (0.8, [0.8 - width / 2, 0.8 + width / 2], width / 2)})
        runs.append({"rows": rows})
    return runs


def test_a_world_fails_only_when_significantly_under_090_counting_runs():
    ok = bu.summarise(_runs([True] * 51 + [False] * 9), "known")  # 0.85 of 60: not significantly under 0.90
    assert ok["runs"] == 60 and ok["coverage"] == pytest.approx(0.85) and ok["points"] == 180
    bad = bu.summarise(_runs([True] * 45 + [False] * 15), "known")  # 0.75 of 60: it is
    lines = bu.verdicts([{"world": "engine10", "path": "map", **ok}, {"world": "ageing8", "path": "map", **bad}],
                        quick=False)
    assert lines[0].startswith("pass: world engine10, path map: coverage 0.850 of 60 runs")
    assert lines[2].startswith("FAIL: world ageing8, path map: coverage 0.750")
    assert all(x.startswith("pass") for x in (lines[1], lines[3]))  # 20 pp wide: within the map's 40 pp


def test_the_width_caps_are_per_path():
    wide = bu.summarise(_runs([True] * 60, width=0.12), "known")  # 12 pp: fine for the map, too wide for input
    lines = bu.verdicts([{"world": "own", "path": "map", **wide}, {"world": "own", "path": "input", **wide}],
                        quick=False)
    assert lines[1].startswith("pass: world own, path map: mean width 12.0 pp (cap 40 pp)")
    assert lines[3].startswith("FAIL: world own, path input: mean width 12.0 pp (cap 10 pp)")
    eleven = bu.summarise(_runs([True] * 4, width=0.11), "known")
    assert bu.verdicts([{"world": "own", "path": "input", **eleven}], quick=False)[1].startswith("FAIL")
    quick = bu.verdicts([{"world": "own", "path": "input", **eleven}], quick=True)  # the quick mode's looser cap
    assert quick[1].startswith("pass") and "cap 12 pp" in quick[1]
    # a world reported, not judged, gives no verdict
    assert bu.verdicts([{"world": "calslope3", "path": "map", **wide}], quick=False) == []
