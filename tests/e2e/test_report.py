"""report.html: every `dyno run` writes one, `dyno report RUN` rebuilds it (legacy imports too), and its
figures hold the run's points."""

from __future__ import annotations

import base64
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.datapaths import legacy_data_dir, legacy_data_missing
from dyno.report.html import ReportData, render_report

REPO = Path(__file__).resolve().parents[2]


def _dyno(*args, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd, env=dict(os.environ, PYTHONPATH=str(REPO)))


def _data_block(page: str) -> dict:
    m = re.search(r'<script type="application/json" id="dyno-report-data">(.*?)</script>', page, re.S)
    assert m, "no data block"
    return json.loads(m.group(1))


def _svg(page: str, fig_id: str) -> str:
    m = re.search(rf'<img class="fig" id="{fig_id}"[^>]*src="data:image/svg\+xml;base64,([^"]+)"', page)
    assert m, f"no figure {fig_id}"
    return base64.b64decode(m.group(1)).decode("utf-8")


def _markers(svg: str, gid: str) -> list[tuple[float, float]]:
    """(x, y) of every marker drawn in the SVG group matplotlib wrote for the artist with this gid."""
    start = svg.find(f'<g id="{gid}">')
    assert start >= 0, f"no series {gid} in the figure"
    depth, pos, end = 0, start, None
    for m in re.finditer(r"<g\b|</g>", svg[start:]):
        depth += 1 if m.group(0) == "<g" else -1
        if depth == 0:
            end = start + m.end()
            break
    group = svg[pos:end]
    return [(float(x), float(y)) for x, y in re.findall(r'<use [^>]*x="([-\d.]+)" y="([-\d.]+)"', group)]


def _valid(points: list) -> list:
    return [p for p in points if p.get("valid", True) and not p.get("discarded")]


def test_run_writes_a_self_contained_report_with_its_points(cli_run):
    run_dir, doc = cli_run
    page = (run_dir / "report.html").read_text(encoding="utf-8")
    pts = _valid(doc["points"])
    assert len(pts) >= 10
    # self-contained: nothing fetched (figures are data: URIs, no external script or style)
    assert not re.findall(r'(?:src|href)="(?!data:)', page) and "<link" not in page
    for section in ("Summary", "Efficiency", "Shift curve", "Torque and power", "Points",
                    "Aborts, faults and discarded points", "Calibration", "Engine map", "CVT tune", "Versions"):
        assert f"<h2>{section}</h2>" in page, section
    assert "success" in page and "108.188" in page and "cvtech" in page.lower()
    # the term that dominates U95, from the points' own terms (rms over them), and what `dyno compare` cancels
    names = {n for p in doc["points"] for n in (p.get("efficiency_u95_terms") or {})}
    rms = {n: math.sqrt(sum((p["efficiency_u95_terms"].get(n) or 0.0) ** 2 for p in doc["points"]
                            if p.get("efficiency_u95_terms")) / sum(1 for p in doc["points"]
                                                                     if p.get("efficiency_u95_terms")))
           for n in names}
    largest = max(rms, key=rms.get)
    m = re.search(r'<p id="u95-largest"><b>largest U95 term: (\w+) \(±([\d.]+) pp', page)
    assert m and m.group(1) == largest and float(m.group(2)) == pytest.approx(100 * rms[largest], abs=0.051), m
    assert "`dyno compare` cancels what two runs share" in page
    # the shipped map is no engine's and its term dominates: the report says what narrows the interval
    assert largest == "engine_map" and '<p id="u95-advice"><b>To narrow:</b> the engine map is not measured' in page

    data = _data_block(page)
    eff = data["efficiency"]["points"]
    assert eff["index"] == [p["index"] for p in pts]
    assert eff["efficiency"] == pytest.approx([p["efficiency"] for p in pts], rel=1e-12)
    assert eff["rpm_secondary"] == pytest.approx([p["rpm_secondary"] for p in pts], rel=1e-12)
    assert eff["efficiency_sem"] == pytest.approx([p["efficiency_sem"] for p in pts], rel=1e-12)
    model = data["efficiency"]["model"]  # the belt-model overlay is there: the full model where the cache has
    assert model["efficiency"] or model["bound"]["efficiency"]  # it, else the closed form named a bound
    if model["tier"] != "full":
        assert "upper bound" in model["label"] and "--model full" in model["label"]
        assert "eff-model-bound" in _svg(page, "fig-efficiency")

    # the figure draws exactly these points, where they belong: x grows with secondary rpm, y with efficiency
    marks = _markers(_svg(page, "fig-efficiency"), "eff-points")
    assert len(marks) == len(pts)
    by_rpm = sorted(range(len(pts)), key=lambda k: pts[k]["rpm_secondary"])
    assert [marks[k][0] for k in by_rpm] == sorted(m[0] for m in marks)
    by_eff = sorted(range(len(pts)), key=lambda k: pts[k]["efficiency"])
    assert [marks[k][1] for k in by_eff] == sorted((m[1] for m in marks), reverse=True)  # SVG y points down
    assert len(_markers(_svg(page, "fig-shift"), "shift-points")) == len(pts)
    tp = _svg(page, "fig-torque-power")
    for gid in ("torque-points", "power-out-points", "power-in-points"):
        assert len(_markers(tp, gid)) == len(pts), gid
    assert "<g id=\"shift-predicted\">" in _svg(page, "fig-shift")  # the tune's predicted curve


def test_dyno_report_rebuilds_it(cli_run, tmp_path):
    run_dir, _ = cli_run
    out = tmp_path / "again.html"
    proc = _dyno("report", run_dir, "--out", out, cwd=tmp_path)
    assert proc.returncode == 0 and proc.stdout.strip() == str(out), proc.stderr
    before, after = (run_dir / "report.html").read_text(), out.read_text()
    assert _data_block(after)["efficiency"] == _data_block(before)["efficiency"]


def test_report_shows_the_full_model_where_cached_and_the_bound_only_as_a_labelled_bound(cli_run, tmp_path):
    """A run whose UI overlay solved some points: the report shows the full model (with losses) there, the
    closed form only for the rest, as its own dashed series named an upper bound -- and the physics holds:
    the full model's efficiency is below the creep-only bound at the same point."""
    from dyno.report.html import exclusion_reason
    from dyno.model.overlay import predict_overlay
    from dyno.runlog.reader import load_run
    from dyno.model.overlay_inputs import overlay_inputs

    run_dir, _ = cli_run
    cache = tmp_path / "cache"
    run = load_run(run_dir, with_events=False)
    kept = [p for p in run.docs("point") if not exclusion_reason(p) and (p.get("power_in_w") or 0) > 0]
    pairs = overlay_inputs(kept, run_dir / "tune.toml")
    assert len(pairs) >= 6
    # as the UI's overlay would have: the two lightest-loaded points (the default sim's first-estimate clamp
    # leaves the belt in gross slip at full load -- docs/belt-model.md, "The stock tune's clamp")
    pairs.sort(key=lambda xo: xo[1].primary_torque_nm)
    solved = predict_overlay([op for _, op in pairs[:2]], tier="full", cache_dir=cache)
    assert solved[0]["converged"], solved[0].get("error")
    n_ok = sum(r["converged"] for r in solved)
    out = tmp_path / "r.html"
    proc = subprocess.run([sys.executable, "-m", "dyno", "report", run_dir, "--out", out], capture_output=True,
                          text=True, timeout=180, cwd=tmp_path,
                          env=dict(os.environ, PYTHONPATH=str(REPO), DYNO_MODEL_CACHE=str(cache)))
    assert proc.returncode == 0, proc.stderr
    page = out.read_text()
    model = _data_block(page)["efficiency"]["model"]
    assert model["tier"] == "mixed" and model["n_full"] == n_ok and model["n_points"] == len(pairs)
    assert "full model" in model["label"] and f"{n_ok} of" in model["label"] and "upper bound" in model["label"]
    ok = [x for (x, _), r in zip(pairs, solved) if r["converged"]]
    assert sorted(model["rpm_secondary"]) == pytest.approx(sorted(ok))
    assert len(model["bound"]["rpm_secondary"]) == len(pairs) - 2
    bound_same = predict_overlay([op for _, op in pairs[:2]], tier="closed_form", use_cache=False)
    for r_full, r_cf in zip(solved, bound_same):
        if r_full["converged"]:
            assert r_full["efficiency"]["overall"] < r_cf["efficiency"]["overall"] - 1e-3  # losses beyond creep
    svg = _svg(page, "fig-efficiency")
    assert len(_markers(svg, "eff-points")) >= 6 and '<g id="eff-model">' in svg and '<g id="eff-model-bound">' in svg
    assert "Belt model: full model" in page


def test_dyno_report_bad_input_is_one_line(cli_run, tmp_path):
    proc = _dyno("report", tmp_path, cwd=tmp_path)  # not a run directory
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "meta.json" in proc.stderr
    proc = _dyno("report", cli_run[0], "--out", tmp_path / "no" / "r.html", cwd=tmp_path)
    assert proc.returncode == 2 and "--out" in proc.stderr and not (tmp_path / "no").exists()


def test_report_of_a_legacy_import(tmp_path):
    why = legacy_data_missing()
    if why:
        pytest.skip(why)
    run = tmp_path / "legacy"
    assert _dyno("import-legacy", legacy_data_dir() / "2019-04-18_run2", "--out", run,
                 cwd=tmp_path).returncode == 0
    proc = _dyno("report", run, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    page = (run / "report.html").read_text(encoding="utf-8")
    data = _data_block(page)
    assert 0 in data["efficiency"]["excluded"]["index"]  # the team's discarded point 0, shown apart
    assert 0 not in data["efficiency"]["points"]["index"]
    assert len(_markers(_svg(page, "fig-efficiency"), "eff-excluded")) == len(data["efficiency"]["excluded"]["index"])
    assert "Import faults" in page and "legacy-import" in page and "2019-04-18_run2" in page


def test_report_of_an_aborted_run(tmp_path):
    from dyno.session.root import RunSpec, run_test
    from dyno.session.drills import parse_drill
    from dyno.report.writer import write_report

    out = tmp_path / "aborted"
    result = run_test(RunSpec(sim=True, seed=2, out_dir=out, drills=[parse_drill("overtemp@45")]))
    assert result["state"] == "aborted"
    page = write_report(out).read_text(encoding="utf-8")
    assert '<span class="bad">abort</span>' in page and "<h3>Aborts</h3>" in page
    assert result["aborts"][0]["cause"] in page


def _synthetic(points, **kw) -> ReportData:
    docs = [{"type": "point", **p} for p in points] + [{"type": "stop", "exit_status": "success", "reason": "ok"}]
    return ReportData(run_dir="/runs/x", meta={"mode": "sim"}, documents=docs, **kw)


def test_report_flags_implausible_efficiency_and_survives_hostile_text():
    good = {"index": 0, "rpm_primary": 3000.0, "rpm_secondary": 2000.0, "ratio": 1.5, "torque_secondary_nm": 20.0,
            "power_out_w": 4000.0, "power_in_w": 5000.0, "efficiency": 0.8, "efficiency_sem": 0.01}
    over = dict(good, index=1, efficiency=1.35)
    nan = dict(good, index=2, efficiency=math.nan, power_in_w=math.nan)
    page = render_report(_synthetic([good, over, nan], notes=["</script><b>x</b>"]))
    data = _data_block(page)  # still parses: the note cannot close the data block
    assert data["efficiency"]["points"]["index"] == [0]
    assert data["efficiency"]["excluded"]["index"] == [1]
    assert "implausible efficiency 135.0 %" in page and "no efficiency" in page
    assert "&lt;/script&gt;&lt;b&gt;x&lt;/b&gt;" in page


def test_run_report_failure_is_one_line_and_keeps_the_exit_code(tmp_path, capsys, monkeypatch):
    from dyno.cli import run_cmd

    run_cmd._write_report({"run_dir": str(tmp_path / "gone")}, announce=True)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "report.html not written" in err

    import dyno.report.writer as writer

    def broken(run_dir):
        raise RuntimeError("matplotlib exploded")
    monkeypatch.setattr(writer, "write_report", broken)
    (tmp_path / "meta.json").write_text("{}")
    run_cmd._write_report({"run_dir": str(tmp_path)}, announce=True)
    out = capsys.readouterr()
    assert out.err.count("\n") == 1 and "matplotlib exploded" in out.err and out.out == ""
