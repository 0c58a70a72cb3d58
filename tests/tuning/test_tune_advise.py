"""dyno tune advise as a team uses it, on a simulated rig whose parts are not their labels
(--sim-tune-deviation 0.1): engagement run -> advise -> fit the advised parts -> run again. Judged on
the sim's truth, not on what the advisor says about itself."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.control.plans import plan_named
from dyno.sim.rig_params import RigParams

STOCK = Path("calibration/tunes/cvtech-stock.toml").resolve()
WORLD = 23
TARGETS = {"engagement": 2300.0, "shift_out": 2850.0}  # (the stock rig of world 23: 2,298 / 2,667 rpm true at rest)


def _run(tune: Path, seed: int, out: Path) -> dict:
    # in-process on the sim's loss-model efficiency: the belt-model table costs ~90 s per new tune
    return run_test(RunSpec(sim=True, seed=seed, out_dir=out, tune_path=tune, plan=plan_named("engagement"),
                               sim_params=RigParams(cvt_tune_path=str(tune), tune_deviation_rel=0.1,
                                                    world_seed=WORLD, belt_efficiency_source="loss_model")))


def _dyno(*args, env=None, timeout=300):
    return subprocess.run([sys.executable, "-m", "dyno", *args], capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("advise")
    runs = tmp / "runs"
    env = {"DYNO_RUNS_DIR": str(runs)}
    # the shipped catalogue but the team's example part: it states +-2 % (weighed), while the sim draws every
    # part within +-10 %
    cat = tmp / "parts"
    cat.mkdir()
    for f in Path("calibration/parts").glob("*.toml"):
        if not f.name.startswith("team-"):
            shutil.copy(f, cat / f.name)
    first = _run(STOCK, 1, runs / "r1")
    adv = _dyno("tune", "advise", str(runs / "r1"), "--target", "engagement=2300", "--target", "shift_out=2850",
                "--catalogue", str(cat), "--out", str(tmp / "advice"), "--json", env=env)
    assert adv.returncode == 0, adv.stderr[-2000:]
    advice = json.loads(adv.stdout)
    second = _run(Path(advice["tunes"][0]["tune_file"]), 2, runs / "r2")
    return {"tmp": tmp, "env": env, "first": first, "advice": advice, "second": second}


def test_advice_moves_the_true_figures_to_the_targets_within_its_uncertainty(loop):
    first, second, best = loop["first"], loop["second"], loop["advice"]["tunes"][0]
    for fig, target in TARGETS.items():
        before = abs(first[f"{fig}_rpm_true"] - target)
        after = abs(second[f"{fig}_rpm_true"] - target)
        assert after < max(before, 50.0), (fig, before, after)
        pred = best["predicted"][fig]
        assert abs(second[f"{fig}_rpm_true"] - pred["rpm"]) <= pred["u95_rpm"], (fig, pred, second[f"{fig}_rpm_true"])
    # the start was off target on the true rig, so there was something to advise
    assert max(abs(first[f"{f}_rpm_true"] - t) for f, t in TARGETS.items()) > 50.0


def test_advice_documents_and_files(loop):
    a = loop["advice"]
    assert 1 <= len(a["tunes"]) <= 5 and a["searched"] > 1000
    # ranked by the chance within two trips (this one or an adjustment of the same parts next), which is
    # never below this trip's
    p2 = [round(t["p_within_two_trips"], 2) for t in a["tunes"]]
    assert p2 == sorted(p2, reverse=True)
    assert all(t["p_within_two_trips"] >= t["p_within_tolerance"] for t in a["tunes"])
    assert all(t["changes"] for t in a["tunes"])  # the measured tune is never the advice
    for t in a["tunes"]:
        assert len(t["changes"]) <= 2 and Path(t["tune_file"]).is_file()
        assert set(t["predicted"]) == {"engagement", "shift_out"}
        assert all(v["u_rpm"] > 0 for v in t["predicted"].values())
    html = Path(a["html"]).read_text()
    assert "<svg" in html and "Ranked tunes" in html
    # the calibration: the stock parts' effective values with their uncertainty below the prior's
    cal = a["calibration"]["parameters"]
    assert any(c["u_rel"] < c["prior_sd_rel"] for c in cal)
    # what it was calibrated on: the engagement run's figures (the engagement plan's shift-out vs load rows)
    on = a["calibrated_on"]
    assert [c["run"] for c in on] == ["r1"] and on[0]["engagement_figures"] >= 1 and on[0]["shift_out_figures"] >= 1


def test_the_run_library_shows_advised_beside_measured(loop):
    r = _dyno("runs", "--json", env=loop["env"])
    assert r.returncode == 0, r.stderr
    rows = {Path(x["path"]).name: x for x in json.loads(r.stdout)["runs"]}
    assert "advised" not in rows["r1"]
    adv = rows["r2"]["advised"]["figures"]
    assert adv["engagement"]["measured_rpm"] == pytest.approx(loop["second"]["engagement_rpm"])
    assert adv["engagement"]["predicted_rpm"] == pytest.approx(loop["advice"]["tunes"][0]["predicted"]["engagement"]["rpm"])
    table = _dyno("runs", env=loop["env"])
    assert "advised: engagement predicted" in table.stdout and "measured" in table.stdout
    # the advised tune's name ends in the parts changed: the table keeps that end when it clips the name
    assert rows["r2"]["tune_name"][-12:] in table.stdout


def test_the_runs_own_summary_shows_its_figures_and_the_advice(loop, monkeypatch, capsys):
    """`dyno run`'s text summary of an engagement run (no points table): the figures it measured, the tune's
    label prediction, and the advisor's prediction beside the measurement (the same function prints it)."""
    from dyno.cli.run_cmd import print_result_table

    monkeypatch.setenv("DYNO_RUNS_DIR", loop["env"]["DYNO_RUNS_DIR"])
    second = loop["second"]
    print_result_table(second)
    out = capsys.readouterr().out
    assert "rpm_p" not in out  # no empty table
    assert f"engagement {second['engagement_rpm']:.0f} ± " in out and f"shift-out {second['shift_out_rpm']:.0f}" in out
    pred = loop["advice"]["tunes"][0]["predicted"]["engagement"]
    assert (f"advised: engagement predicted {pred['rpm']:.0f} ± {pred['u95_rpm']:.0f}, "
            f"measured {second['engagement_rpm']:.0f}") in out
    print_result_table(loop["first"])  # the stock tune was never advised
    assert "advised:" not in capsys.readouterr().out
    # and its report.html, which `dyno run` writes at the end (and `dyno report RUN` again)
    from dyno.report.writer import write_report

    page = write_report(second["run_dir"], out=loop["tmp"] / "r2-report.html").read_text()
    assert 'id="advised"' in page and f"<td>{pred['rpm']:.0f}</td>" in page
    assert f"<td>{second['engagement_rpm']:.0f}</td>" in page
    stock = write_report(loop["first"]["run_dir"], out=loop["tmp"] / "r1-report.html").read_text()
    assert 'id="advised"' not in stock


def test_the_advice_says_when_the_targets_are_out_of_reach(loop, tmp_path):
    assert loop["advice"]["verdict"].startswith("reachable")  # (the loop's targets were reached, above)
    r1 = str(loop["tmp"] / "runs" / "r1")
    # an engagement far above the catalogue's reach with the shift-out at its stock value: no P worth a trip
    far = _dyno("tune", "advise", r1, "--target", "engagement=2900", "--target", "shift_out=2750",
                "--out", str(tmp_path / "far"), env=loop["env"])
    assert far.returncode == 0, far.stderr[-1500:]
    assert "out of reach: no tune with at most 2 parts changed" in far.stdout, far.stdout[-1500:]
    none = _dyno("tune", "advise", r1, "--target", "engagement=2100", "--max-changes", "0", "--json",
                 "--out", str(tmp_path / "none"), env=loop["env"])
    assert none.returncode == 0, none.stderr[-1500:]
    doc = json.loads(none.stdout)
    assert doc["tunes"] == [] and doc["verdict"].startswith("no tune to advise")


@pytest.mark.parametrize("args, what", [
    (["--target", "engagment=2100"], "--target"),
    (["--target", "engagement=fast"], "--target engagement"),
    (["--target", "engagement=2100", "--catalogue", "nowhere"], "nowhere"),
    (["--target", "engagement=2100", "--target", "engagement=2000"], "one target per figure"),
])
def test_bad_input_one_line_exit_2_nothing_written(loop, tmp_path, args, what):
    out = tmp_path / "adv"
    r = _dyno("tune", "advise", str(loop["tmp"] / "runs" / "r1"), *args, "--out", str(out), env=loop["env"])
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and what in r.stderr, r.stderr
    assert not out.exists()


def test_a_run_that_is_not_an_engagement_run_is_refused(tmp_path):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "meta.json").write_text("{}")
    (tmp_path / "r" / "tune.toml").write_text(STOCK.read_text())
    r = _dyno("tune", "advise", str(tmp_path / "r"), "--target", "engagement=2100", "--out", str(tmp_path / "a"))
    assert r.returncode == 2 and "characterisation" in r.stderr and r.stderr.count("\n") == 1
    assert not (tmp_path / "a").exists()


def test_steady_points_calibrate_the_full_load_figure(loop):
    """A speed-hold run's steady points (the closed-form shift model's effective f, dr, T_fr) beside the
    engagement run: the steady residuals shrink from the nominal model's, and the engagement figures
    still sit within their sigmas (the steady points' model error does not leak into the parts)."""
    import numpy as np

    from dyno.tuning.advisor import tolerance_lookup
    from dyno.tuning.advisor_model import calibrate, load_run_data
    from dyno.tuning.fit import NOMINAL, newton_residual_rpm, solver_for
    from dyno.tuning.parts import load_catalogue

    sh = run_test(RunSpec(sim=True, seed=5, out_dir=loop["tmp"] / "sh", tune_path=STOCK,
                             plan=plan_named("speed-hold"),
                             sim_params=RigParams(cvt_tune_path=str(STOCK), tune_deviation_rel=0.1, world_seed=WORLD,
                                                  belt_efficiency_source="loss_model")))
    assert sh["state"] == "done"
    eng, steady = load_run_data(loop["tmp"] / "runs" / "r1"), load_run_data(loop["tmp"] / "sh")
    assert len(steady.steady) >= 4 and not steady.figures
    tol = tolerance_lookup(load_catalogue("calibration/parts"), [eng.tune])
    both = calibrate([eng, steady], tol)
    rows = [r for r in both.residuals if r["figure"] == "steady"]
    assert len(rows) >= 4
    nominal = [newton_residual_rpm(solver_for(steady.tune, steady.engine, NOMINAL), p) for p in steady.steady]
    assert np.sqrt(np.mean([r["residual_rpm"] ** 2 for r in rows])) < np.sqrt(np.mean(np.square(nominal)))
    sig = {(f.figure, round(f.load_nm, 6)): f.sigma_rpm for f in eng.figures}
    for r in both.residuals:
        if r["figure"] != "steady":
            assert abs(r["residual_rpm"]) < 3 * sig[(r["figure"], round(r["load_nm"], 6))], r


def test_advice_page_in_a_browser(loop):
    """advice.html in headless Chromium: the ranked table, the curves' figure drawn, no script errors."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed (pip install -e '.[webtest]'; .ci/run does)")
    if not Path("/usr/bin/chromium").exists():
        pytest.skip("/usr/bin/chromium is missing (apt-get install chromium; .ci/run does)")
    errors = []
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path="/usr/bin/chromium", args=["--no-sandbox"], headless=True)
        try:
            page = b.new_page()
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(Path(loop["advice"]["html"]).resolve().as_uri())
            rows = page.locator("table").first.locator("tr")
            assert rows.count() == len(loop["advice"]["tunes"]) + 1
            box = page.locator("svg").first.bounding_box()
            assert box is not None and box["width"] > 300 and box["height"] > 200
            assert page.locator("svg path").count() > 10  # the curves and axes are drawn
            assert "P(all targets met)" in page.content()
        finally:
            b.close()
    assert not errors


def test_pool_and_inline_give_the_same_advice(loop, tmp_path):
    """The refine step through dyno.model.executor: a local pool of 2 gives what this process gives."""
    docs = []
    for jobs in ("1", "2"):
        r = _dyno("tune", "advise", str(loop["tmp"] / "runs" / "r1"), "--target", "engagement=2300",
                  "--target", "shift_out=2850", "--jobs", jobs, "--out", str(tmp_path / jobs), "--json",
                  env={"DYNO_RUNS_DIR": str(tmp_path / "runs")})
        assert r.returncode == 0, r.stderr[-2000:]
        docs.append(json.loads(r.stdout))
    assert [t["changes"] for t in docs[0]["tunes"]] == [t["changes"] for t in docs[1]["tunes"]]
    assert [t["predicted"] for t in docs[0]["tunes"]] == [t["predicted"] for t in docs[1]["tunes"]]
