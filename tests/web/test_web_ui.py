"""`dyno ui --sim --web` in a real terminal (tmux: the TUI needs one) and its page in headless chromium: the page
follows the operator's screen (ARMED, then the test after GO on the keyboard), the rpm moves, a drill's abort
banner with its cause and the rig's safety as the physics has it; the page has no GO, arm or re-arm."""

from __future__ import annotations

import json
import re
import sys
import time

from tests.ui.test_ui_tmux import _env
from tests.web.conftest import http_status, needs_browser, needs_tmux

pytestmark = [needs_browser, needs_tmux]


def test_ui_web_page_follows_the_terminal_session(browser, tmp_path, terminal):
    run_dir = tmp_path / "run"
    cmd = (f"{sys.executable} -m dyno ui --sim --speed 4 --out {run_dir} --drill bus-lost@measure+1 "
           f"--web 127.0.0.1:0 ; echo EXITED=$? ; sleep 30")
    session = terminal(cmd, size=(120, 30), env=_env(tmp_path))
    try:
        screen = session.wait("ARMED", 120)
        m = re.search(r"web: (http://127\.0\.0\.1:\d+/\?token=[\w-]+)", screen)
        assert m, screen
        url = m.group(1)
        base = url.split("/?token=")[0]
        assert http_status(base + "/api/state")[0] == 401
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.goto(url)
        page.wait_for_function("document.getElementById('state').textContent.startsWith('ARMED')", timeout=20_000)
        assert page.query_selector("#stop") is None or not page.is_visible("#stop")  # no --web-stop: no button
        for text in ("GO", "arm"):  # nothing on the page starts or re-arms the rig
            assert page.query_selector(f"button:text-is('{text}')") is None
        session.keys("g")
        session.wait("Start the test?", 10)
        session.keys("y")
        page.wait_for_function("!document.getElementById('state').textContent.startsWith('ARMED')", timeout=20_000)
        seen = set()
        for _ in range(12):
            seen.add(page.inner_text("#rpm-secondary"))
            time.sleep(0.15)
        assert len(seen) >= 3, seen
        page.wait_for_selector("#banner:not([hidden])", timeout=90_000)
        assert page.inner_text("#abort-cause") == "comms_lost"
        page.wait_for_function("document.getElementById('rig-safe').dataset.safe === 'true'", timeout=30_000)
        session.wait(["cause: comms_lost", "rig SAFE"], 20)  # the terminal says the same
        session.keys("q")  # (the test has ended: no confirmation)
        session.wait("EXITED=0", 30)
        page.wait_for_function("document.getElementById('link').textContent.includes('ended')", timeout=10_000)
    finally:
        session.close()
    # the run's own safety record: the drill's abort, the physics safe at its end
    docs = [json.loads(line) for line in (run_dir / "documents.jsonl").read_text().splitlines() if line.strip()]
    safety = [d for d in docs if d.get("type") == "safety"][-1]
    assert safety["aborts"][0]["cause"] == "comms_lost" and safety["rig_safe"] is True
