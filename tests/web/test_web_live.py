"""`dyno run --sim --web` as a process, its page in headless chromium: the rpm moves, the points table grows,
a drill's abort banner shows its cause within 1 s of the drill's onset, the rig's safety as the physics has it;
401 without the token; STOP only with --web-stop."""

from __future__ import annotations

import json
import time

import pytest

from tests.web.conftest import DroppingProxy, DynoProcess, http_status, needs_browser

pytestmark = needs_browser

SPEED = 4.0
DRILL_AT_S = 104.0  # simulated seconds from the first frame: after the second point of the speed hold (the first
# points come at ~84 s: the start-up release's full stroke (~8.9 s, the ignition held off), then the overdrive
# setpoints, in the shift region, are skipped first)

BANNER_WATCH = """
window.__bannerMs = null;
new MutationObserver(() => {
  const b = document.getElementById('banner');
  if (b && !b.hidden && window.__bannerMs === null) window.__bannerMs = Date.now();
}).observe(document, {subtree: true, attributes: true, childList: true, characterData: true});
"""


def _onset_wall_s(log: list, onset_sim_s: float) -> float:
    """The wall time of a simulated instant, between the two frames that bracket it (each frame carries the
    rig loop's clock and the wall clock it was taken at)."""
    pairs = sorted((f["t_sim_s"], f["wall_unix_s"]) for f in log if f.get("t_sim_s") is not None)
    before = [p for p in pairs if p[0] <= onset_sim_s]
    after = [p for p in pairs if p[0] > onset_sim_s]
    assert before and after, "no frames around the drill's onset"
    (s0, w0), (s1, w1) = before[-1], after[0]
    return w0 + (w1 - w0) * (onset_sim_s - s0) / (s1 - s0)


def test_run_web_page_live_values_points_and_drill_banner(browser, tmp_path):
    run_dir = tmp_path / "run"
    p = DynoProcess(["run", "--sim", "--headless", "--json", "--out", run_dir, "--speed", SPEED,
                     "--drill", f"bus-lost@{DRILL_AT_S:g}", "--web", "127.0.0.1:0"], cwd=tmp_path)
    try:
        url = p.wait_url()
        assert url.startswith("http://127.0.0.1:")
        # the token on every endpoint: without it (or a wrong one) 401, never the data or a redirect
        for path in ("/", "/api/state", "/api/events", "/static/live.js"):
            assert http_status(p.base + path)[0] == 401, path
            assert http_status(p.base + path + "?token=wrong")[0] == 401, path
        assert http_status(p.base + "/api/stop?token=" + p.token, "POST")[0] == 403  # no --web-stop: no STOP
        for _ in range(100):  # (the rig's first frame comes once the run is built)
            code, body = http_status(p.base + "/api/state?token=" + p.token)
            assert code == 200
            if "rpm_secondary" in json.loads(body):
                break
            time.sleep(0.2)
        assert json.loads(body)["rpm_secondary"] is not None

        page = browser.new_page(viewport={"width": 390, "height": 844})  # a phone
        page.add_init_script(BANNER_WATCH)
        page.goto(url)
        page.wait_for_function("document.getElementById('rpm-primary').textContent !== '—'", timeout=30_000)
        # the engine starts once the start-up release has run its full stroke (the ignition is held off till
        # then: docs/safety.md): wait for it to turn, then the page must follow its speed
        page.wait_for_function("parseFloat(document.getElementById('rpm-primary').textContent) > 0", timeout=60_000)
        seen = set()
        for _ in range(12):
            seen.add(page.inner_text("#rpm-primary"))
            time.sleep(0.15)
        assert len(seen) >= 3, f"the primary rpm on the page did not change: {seen}"
        # usable at phone width: nothing wider than the screen (the points table scrolls in its own box)
        assert page.evaluate("document.documentElement.scrollWidth") <= 390
        page.wait_for_function("document.querySelectorAll('#points tbody tr').length >= 1", timeout=60_000)
        page.wait_for_function("document.querySelectorAll('#points tbody tr').length >= 2", timeout=60_000)
        page.wait_for_selector("#banner:not([hidden])", timeout=60_000)
        assert page.inner_text("#abort-cause") == "comms_lost"
        page.wait_for_function("document.getElementById('rig-safe').dataset.safe === 'true'", timeout=60_000)
        banner_ms = page.evaluate("window.__bannerMs")
        log = page.evaluate("window.dynoLog")
        rows = page.query_selector_all("#points tbody tr")
        table = [[td.inner_text() for td in r.query_selector_all("td")] for r in rows]
        assert p.wait(120) == 3, "".join(p.stderr_lines)  # aborted to the safe state
    finally:
        p.stop()
    result = json.loads(p.stdout)
    assert "Traceback" not in "".join(p.stderr_lines)
    # the abort the page showed is the run's, and its onset is the drill's (the simulated world's time)
    abort = result["aborts"][0]
    assert abort["cause"] == "comms_lost" and abort["drill"] == f"bus-lost@{DRILL_AT_S:g}"
    # >= 5 updates a second while the test runs (the page's own receipt times)
    recv = sorted(f["recv_ms"] for f in log if f["state"] in ("warmup", "step", "settle", "measure"))
    gaps_s = sorted((b - a) / 1000.0 for a, b in zip(recv, recv[1:]))
    assert len(gaps_s) > 20 and gaps_s[len(gaps_s) // 2] <= 0.2, gaps_s[len(gaps_s) // 2]
    latency_s = banner_ms / 1000.0 - _onset_wall_s(log, abort["onset_s"])
    # within 1 s, or five of the page's own update gaps where a loaded machine stretched them (this run's median)
    assert 0.0 < latency_s < max(1.0, 5 * gaps_s[len(gaps_s) // 2]), f"banner {latency_s:.3f} s after the onset"
    # the rig safe as the physics has it (pads off the rotor, engine killed), as the page said
    assert result["rig_safe"] is True and result["outputs"]["safe"] is True
    # the table is the run's points, newest first; their secondary speeds are the simulated rig's within 2 %
    assert len(table) == len(result["points"]) >= 2
    for row, pt in zip(reversed(table), result["points"]):
        assert int(row[0]) == pt["index"]
        assert abs(float(row[2]) - pt["rpm_secondary_true"]) < 0.02 * pt["rpm_secondary_true"]


def test_run_web_reconnects_after_a_network_drop_and_stop_aborts_through_the_estop_path(browser, tmp_path):
    """The page, through a link that drops for 3 s, says so and comes back live by itself; then --web-stop:
    the page's STOP is the E-STOP key's abort (cause estop); the physics ends safe."""
    p = DynoProcess(["run", "--sim", "--headless", "--json", "--out", tmp_path / "run", "--speed", SPEED,
                     "--web", "127.0.0.1:0", "--web-stop"], cwd=tmp_path)
    proxy = None
    try:
        p.wait_url()
        proxy = DroppingProxy("127.0.0.1", int(p.base.rsplit(":", 1)[1]))
        page = browser.new_page()
        page.goto(f"http://127.0.0.1:{proxy.port}/?token={p.token}")
        page.wait_for_function("document.getElementById('rpm-primary').textContent !== '—'", timeout=30_000)
        # the engine starts once the start-up release has run its full stroke (the ignition is held off till
        # then: docs/safety.md): wait for it to turn, then the page must follow its speed
        page.wait_for_function("parseFloat(document.getElementById('rpm-primary').textContent) > 0", timeout=60_000)
        assert page.inner_text("#link") == "live"
        proxy.drop(3.0)
        page.wait_for_function("document.getElementById('link').textContent.includes('reconnecting')", timeout=5_000)
        before = page.inner_text("#rpm-primary")
        page.wait_for_function("document.getElementById('link').textContent === 'live'", timeout=20_000)
        page.wait_for_function(f"document.getElementById('rpm-primary').textContent !== {before!r}", timeout=10_000)
        page.wait_for_selector("#stop", state="visible")
        page.on("dialog", lambda d: d.accept())
        page.click("#stop")
        page.wait_for_selector("#banner:not([hidden])", timeout=20_000)
        assert page.inner_text("#abort-cause") == "estop"
        assert p.wait(120) == 3
    finally:
        p.stop()
        if proxy is not None:
            proxy.close()
    result = json.loads(p.stdout)
    assert result["aborts"][0]["cause"] == "estop" and "web page STOP" in result["aborts"][0]["detail"]
    assert result["rig_safe"] is True


@pytest.mark.parametrize("bind", ["127.0.0.1:99999", "nonsense:port"])
def test_run_web_bad_bind_is_one_line_exit_2(tmp_path, bind):
    p = DynoProcess(["run", "--sim", "--headless", "--out", tmp_path / "run", "--web", bind], cwd=tmp_path)
    assert p.wait(60) == 2
    err = "".join(p.stderr_lines)
    assert len(err.strip().splitlines()) == 1 and "--web" in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()
