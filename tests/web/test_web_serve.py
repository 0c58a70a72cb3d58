"""`dyno serve RUNS_DIR` as a process, its pages in headless chromium: the run list and its filters, a run's
report, a comparison of two runs, downloads; 401 without the token; traversal attempts refused (400/403/404),
bad requests a status, never a traceback."""

from __future__ import annotations

import csv
import http.client
import io
import json
import subprocess
import sys
import urllib.parse

import pytest

from tests.web.conftest import REPO, DynoProcess, http_status, needs_browser

pytestmark = [pytest.mark.quick, needs_browser]


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """Three simulated runs made as a user makes them: two complete sweeps (seeds 1, 2), one aborted by a drill."""
    import os

    root = tmp_path_factory.mktemp("library")
    env = dict(os.environ, PYTHONPATH=str(REPO), DYNO_RUNS_DIR=str(root))
    jobs = {name: subprocess.Popen([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--json", "--out",
                                    str(root / name), *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                   text=True, env=env, cwd=root)
            for name, extra in (("done-a", ["--seed", "1", "--plan", "sweep"]),  # (the quickest complete plan)
                                ("done-b", ["--seed", "2", "--plan", "sweep"]),
                                ("aborted-c", ["--seed", "3", "--drill", "bus-lost@5"]))}
    docs = {}
    for name, job in jobs.items():
        out, err = job.communicate(timeout=300)
        assert job.returncode in (0, 3), err[-2000:]
        docs[name] = json.loads(out)
    assert docs["aborted-c"]["state"] == "aborted" and docs["done-a"]["state"] == "done"
    return root, docs


@pytest.fixture(scope="module")
def served(library):
    root, _ = library
    p = DynoProcess(["serve", root, "--bind", "127.0.0.1:0"], cwd=root)
    p.wait_url()
    yield p
    p.stop()
    assert "Traceback" not in "".join(p.stderr_lines)


def _raw(p, path: str) -> tuple[int, str]:
    """A request exactly as written (no client-side normalisation of '..' or '%2f')."""
    u = urllib.parse.urlsplit(p.base)
    c = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
    c.putrequest("GET", path, skip_accept_encoding=True)
    c.endheaders()
    r = c.getresponse()
    body = r.read(4000).decode(errors="replace")
    c.close()
    return r.status, body


def test_serve_list_filter_report_compare(browser, served, library):
    root, docs = library
    assert http_status(served.base + "/")[0] == 401
    assert http_status(served.base + "/api/runs")[0] == 401
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    page.goto(served.url)
    assert sorted(r.get_attribute("data-run") for r in page.query_selector_all("#runs tbody tr")) == \
        ["aborted-c", "done-a", "done-b"]
    page.select_option("select[name=state]", "aborted")  # the filter form: only the aborted run
    page.click("form[action='/'] button")
    page.wait_for_url("**state=aborted**")
    rows = page.query_selector_all("#runs tbody tr")
    assert [r.get_attribute("data-run") for r in rows] == ["aborted-c"]
    assert rows[0].query_selector(".state").inner_text() == "aborted"
    page.goto(served.url + "&since=2000-01-01&tune=no-such-tune")
    assert page.query_selector_all("#runs tbody tr") == []
    page.goto(served.url)
    # a run's report.html, as `dyno run` wrote it
    page.click("tr[data-run='done-a'] a.report")
    page.wait_for_load_state()
    assert "dyno report" in page.title() and "done-a" in page.title()
    page.go_back()
    # compare the two complete runs: dyno compare's page, made in memory
    page.check("input[value='done-a']")
    page.check("input[value='done-b']")
    page.click("form[action='/compare'] button")
    page.wait_for_url("**/compare**")
    assert "Run comparison" in page.inner_text("h1")
    assert "done-a" in page.content() and "done-b" in page.content()
    assert not list(root.glob("compare-*.html"))  # nothing written into the library
    # downloads: the points as CSV are the run's points
    code, body = http_status(f"{served.base}/runs/done-a/points.csv?token={served.token}")
    assert code == 200
    rows = list(csv.DictReader(io.StringIO(body)))
    assert [int(r["index"]) for r in rows] == [p["index"] for p in docs["done-a"]["points"]]
    code, body = http_status(f"{served.base}/runs/done-a/files/meta.json?token={served.token}")
    assert code == 200 and json.loads(body)["seed"] == 1


@pytest.mark.parametrize("path", [
    "/runs/../../../etc/passwd", "/runs/..%2f..%2f..%2fetc%2fpasswd", "/runs/done-a/../done-b/report.html",
    "/runs/%2e%2e/%2e%2e/etc/passwd", "/runs/done-a/files/..%2f..%2flibrary.sqlite",
    "/runs/done-a/files/../../library.sqlite", "/runs/done-a/files/%2fetc%2fpasswd", "/runs/done-a%2f..%2fdone-b/report.html",
    "/runs/no-such-run/report.html", "/runs/done-a/files/no-such-file", "/static/..%2f__init__.py",
    "/static/../__init__.py"])
def test_serve_refuses_paths_outside_the_runs(served, path):
    sep = "&" if "?" in path else "?"
    code, body = _raw(served, f"{path}{sep}token={served.token}")
    assert code in (400, 403, 404), (code, body[:300])
    assert "root:" not in body and "Traceback" not in body and "import" not in body


@pytest.mark.parametrize("query, code", [("/?since=yesterday", 400), ("/?state=exploded", 400),
                                         ("/compare?run=done-a", 400), ("/compare?run=done-a&run=nope", 404),
                                         ("/runs/done-a/nothing", 404)])
def test_serve_bad_requests_get_a_status(served, query, code):
    sep = "&" if "?" in query else "?"
    got, body = _raw(served, f"{query}{sep}token={served.token}")
    assert got == code and "Traceback" not in body, body[:300]


def test_serve_bad_runs_dir_is_one_line_exit_2(tmp_path):
    p = DynoProcess(["serve", tmp_path / "no-such-dir"], cwd=tmp_path)
    assert p.wait(60) == 2
    err = "".join(p.stderr_lines)
    assert len(err.strip().splitlines()) == 1 and "no-such-dir" in err and "Traceback" not in err
