"""Issue 39: the README's main job (`dyno run --sim --headless`, no flags) is air-corrected by the rig's
BME280, and every point's ``efficiency_interval95`` holds the simulated truth (``efficiency_true``).
In-process: the multi-seed checks call the run `dyno run --json` prints (``run_test``, the default plan on
the default simulated rig, without the report it writes after); the others go through ``dyno.cli.main``."""

from __future__ import annotations

import statistics
from pathlib import Path

import pytest

from dyno.cli import main

REPO = Path(__file__).resolve().parents[2]
RIG = (REPO / "hardware" / "rig.toml").read_text()


def _run_test(tmp_path, seed: int, rig: str | None = None) -> dict:
    from dyno.session.root import RunSpec, run_test
    from dyno.cli.run_cmd import plan_named

    return run_test(RunSpec(sim=True, seed=seed, out_dir=tmp_path / f"t{seed}", rig_path=rig,
                               plan=plan_named("speed-hold")))


def _no_sensor_rig(tmp_path, extra: str = "") -> str:
    assert 'sensor = "bme280"' in RIG  # the shipped rig declares its sensor
    rig = tmp_path / "rig-no-sensor.toml"
    rig.write_text(RIG.replace('sensor = "bme280"', 'sensor = "none"', 1).replace("[ambient]", "[ambient]\n" + extra, 1))
    return str(rig)


def _points(result):
    pts = [p for p in result["points"] if p.get("efficiency") is not None and p.get("efficiency_true") is not None]
    assert pts
    return pts


def test_the_default_run_is_air_corrected_and_its_intervals_hold_the_truth(tmp_path):
    inside, u95 = [], []
    for seed in range(6):
        r = _run_test(tmp_path, seed)
        assert r["ambient"]["source"] == "sensor" and r["ambient"]["j1349_factor"] is not None
        for p in _points(r):
            lo, hi = p["efficiency_interval95"]
            assert 0.0 <= lo < p["efficiency"] < hi <= 1.0
            inside.append(lo <= p["efficiency_true"] <= hi)
            u95.append(p["efficiency_u95"])
    # the map path, on a map not measured on this engine (±~10 % of the power): honest, under the 40 pp cap
    assert statistics.fmean(u95) <= 0.20
    assert sum(inside) / len(inside) >= 0.90, (sum(inside), len(inside))


def test_without_a_sensor_the_interval_is_asymmetric_clipped_and_holds_the_truth(tmp_path):
    rig = _no_sensor_rig(tmp_path)
    inside, widths = [], []
    for seed in range(3):
        r = _run_test(tmp_path, seed, rig)
        assert r["ambient"]["source"] == "none"
        for p in _points(r):
            eta, (lo, hi) = p["efficiency"], p["efficiency_interval95"]
            assert hi <= 1.0
            # the day's factor spans ~0.91..1.31 at 95 %: far more room above the figure than below
            assert min(hi, 1.0) - eta > 1.5 * (eta - lo) or hi == 1.0, (lo, eta, hi)
            assert hi == 1.0 or hi - eta != pytest.approx(eta - lo, abs=0.01)
            inside.append(lo <= p["efficiency_true"] <= hi)
            widths.append(hi - lo)
    assert sum(inside) / len(inside) >= 0.90, (sum(inside), len(inside))
    assert statistics.fmean(widths) <= 0.45


def test_the_site_altitude_narrows_the_air_and_places_the_simulated_day(tmp_path):
    from dyno.analysis.air import isa_pressure_kpa

    wide = _run_test(tmp_path, 4, _no_sensor_rig(tmp_path))
    site = _run_test(tmp_path, 5, _no_sensor_rig(tmp_path, "altitude_m = 1500.0"))
    assert site["sim_world"]["pressure_kpa"] == pytest.approx(isa_pressure_kpa(1500.0), abs=4.0)
    w_wide = statistics.fmean(p["efficiency_interval95"][1] - p["efficiency_interval95"][0] for p in _points(wide))
    w_site = statistics.fmean(p["efficiency_interval95"][1] - p["efficiency_interval95"][0] for p in _points(site))
    assert w_site < w_wide  # (both clip at 100 %, and the map's term, the same in both, dominates the width)
    air = [statistics.fmean(p["efficiency_u95_terms"]["air"] for p in _points(r)) for r in (wide, site)]
    assert air[1] < 0.8 * air[0], air  # the air's own term: the site's pressure is known to ±4 kPa
    assert all(lo <= p["efficiency_true"] <= hi for p in _points(site) for lo, hi in [p["efficiency_interval95"]])


def test_a_declared_sensor_that_does_not_answer_refuses_the_run(tmp_path, monkeypatch, capsys):
    from dyno.sim.bme280_chip import SimBME280

    def nack(self, msgs):
        raise OSError(5, "BME280: NACK")

    monkeypatch.setattr(SimBME280, "transaction", nack)
    monkeypatch.chdir(tmp_path)
    rc = main(["run", "--sim", "--headless", "--seed", "1", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "[ambient] sensor" in err[0], err
    assert "Traceback" not in "".join(err) and not (tmp_path / "run" / "meta.json").exists()
