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

    data = _data_block(page)
    eff = data["efficiency"]["points"]
    assert eff["index"] == [p["index"] for p in pts]
    assert eff["efficiency"] == pytest.approx([p["efficiency"] for p in pts], rel=1e-12)
    assert eff["rpm_secondary"] == pytest.approx([p["rpm_secondary"] for p in pts], rel=1e-12)
    assert eff["efficiency_sem"] == pytest.approx([p["efficiency_sem"] for p in pts], rel=1e-12)
    assert data["efficiency"]["model"]["efficiency"]  # the belt-model overlay is there

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
    from dyno.app import RunOptions, run_test
    from dyno.drills import parse_drill
    from dyno.report.writer import write_report

    out = tmp_path / "aborted"
    result = run_test(RunOptions(sim=True, seed=2, out_dir=out, drills=[parse_drill("overtemp@45")]))
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
