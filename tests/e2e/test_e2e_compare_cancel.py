"""dyno compare knows what cancels, on real processes: two runs of ONE simulated rig (same --sim-world-seed:
same engine, same torque sensor) with two tunes, and two runs on different days with no air known.

The simulator records each point's true efficiency, so the stated difference uncertainty U_d is judged
against the true difference (interpolated onto the grid the same way as the measured one)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
TUNES = REPO / "calibration" / "tunes"
SHORT_PLAN = (REPO / "bench" / "bench_uncertainty.py").read_text().split('SHORT_PLAN = """', 1)[1].split('"""', 1)[0]
WORLD = "7"  # one rig: its engine deviates from the map and its sensor's gain drifts (dyno.sim.world)


def _env():
    return dict(os.environ, PYTHONPATH=str(REPO))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Four `dyno run --sim` processes, two at a time: (stock, heavy) with the BME280 on the drawn day;
    (stock, heavy) with no air known, on two different given days."""
    tmp = tmp_path_factory.mktemp("cancel")
    plan = tmp / "short.toml"
    plan.write_text(SHORT_PLAN)
    rig = tmp / "rig.toml"  # (the shipped rig file fits a BME280; this one has none)
    rig.write_text((REPO / "hardware" / "rig.toml").read_text().replace('sensor = "bme280"', 'sensor = "none"', 1))
    specs = {"stock": ("cvtech-stock", 21, []), "heavy": ("heavy-flyweights", 22, []),
             "stock-cold": ("cvtech-stock", 23, ["--sim-ambient", "8,100.5,60", "--rig", str(rig)]),
             "heavy-hot": ("heavy-flyweights", 24, ["--sim-ambient", "34,88,30", "--rig", str(rig)])}
    names = list(specs)
    for pair in (names[:2], names[2:]):
        procs = []
        for name in pair:
            tune, seed, extra = specs[name]
            cmd = [sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--json", "--plan", str(plan),
                   "--seed", str(seed), "--sim-world-seed", WORLD, "--tune", str(TUNES / f"{tune}.toml"),
                   "--out", str(tmp / name), *extra]
            procs.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                          cwd=tmp, env=_env()))
        for p in procs:
            out, err = p.communicate(timeout=600)
            assert p.returncode == 0 and "Traceback" not in err, err[-3000:]
    return tmp


def _compare(a: Path, b: Path, json_out=True):
    cmd = [sys.executable, "-m", "dyno", "compare", "--no-html", *(["--json"] if json_out else []), str(a), str(b)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=_env())
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    return json.loads(proc.stdout) if json_out else proc.stdout


def _arr(x):
    return np.array([np.nan if v is None else v for v in x], dtype=float)


def _own_u95(run_dir: Path) -> float:
    docs = [json.loads(x) for x in (run_dir / "documents.jsonl").read_text().splitlines() if x.strip()]
    # each point's terms in quadrature: its U95 before the interval is clipped at 100 % (with the map not measured
    # on this engine, most points' intervals reach 100 %, and half a clipped width understates what a run knows)
    return min(math.sqrt(sum(v * v for v in d["efficiency_u95_terms"].values()))
               for d in docs if d.get("type") == "point" and d.get("valid"))


def test_one_rig_the_calibration_and_map_cancel_and_u_d_covers_the_truth(runs):
    res = _compare(runs / "stock", runs / "heavy")
    diff = res["differences"][0]
    terms = diff["terms"]
    assert terms["calibration"]["status"] in ("cancelled", "residual")
    assert terms["engine_map"]["status"] in ("cancelled", "residual")
    assert terms["air"]["status"] == "residual"  # both corrected by the sensor: only its tolerance is left
    assert "sensor" in res["atmosphere"] and "not applied" not in res["atmosphere"]
    q = diff["quantities"]["efficiency"]
    d, truth, u95 = _arr(q["difference"]), _arr(q["truth_difference"]), _arr(q["difference_u95"])
    ok = np.isfinite(d) & np.isfinite(truth) & np.isfinite(u95)
    assert ok.sum() >= 5
    assert np.nanmax(np.abs(truth)) > 0.005, "the tunes really differ in efficiency on this rig"
    err = np.abs(d - truth)[ok]
    assert (err <= u95[ok]).all(), list(zip(err, u95[ok]))
    # the terms make the total: U_d^2 = sum of the terms' squares
    parts = np.sqrt(sum(_arr(v) ** 2 for v in q["difference_u95_terms"].values()))
    assert parts[ok] == pytest.approx(u95[ok], rel=1e-9)
    # what cancels is most of each run's own uncertainty (the map's 10 % dominates a single run)
    own = min(_own_u95(runs / "stock"), _own_u95(runs / "heavy"))
    assert np.nanmax(u95) < 0.6 * own and np.nanmedian(u95) < 0.5 * own, (np.nanmax(u95), own)
    # yet more than the statistics alone: the residuals are stated, not dropped
    assert (u95[ok] > 1.959964 * _arr(q["sem"])[ok]).all()


def test_different_days_without_air_the_air_does_not_cancel(runs):
    res = _compare(runs / "stock-cold", runs / "heavy-hot")
    diff = res["differences"][0]
    assert diff["terms"]["air"]["status"] == "not cancelled"
    assert diff["terms"]["calibration"]["status"] == "residual"  # still one rig: these cancel as before
    assert diff["terms"]["engine_map"]["status"] == "residual"
    assert res["atmosphere"].count("uncorrected") == 2
    assert [r["ambient"]["source"] for r in res["runs"]] == ["none", "none"]
    q = diff["quantities"]["efficiency"]
    d, truth, u95 = _arr(q["difference"]), _arr(q["truth_difference"]), _arr(q["difference_u95"])
    air = _arr(q["difference_u95_terms"]["air"])
    ok = np.isfinite(d) & np.isfinite(truth)
    # the two days' J1349 factors differ by ~25 %: the uncorrected efficiencies' difference is far off the truth's,
    # and only the air term (which does not cancel) covers it
    assert np.nanmax(np.abs(d - truth)) > 0.05
    assert (np.abs(d - truth)[ok] <= u95[ok]).all()
    assert (air[ok] > 0.8 * u95[ok]).all()
    text = _compare(runs / "stock-cold", runs / "heavy-hot", json_out=False)
    assert "air: not cancelled" in text and "engine_map: residual" in text
