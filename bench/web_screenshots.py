#!/usr/bin/env python3
"""The screenshots in docs/web.md, taken by Playwright in Debian's chromium (headless) from real processes:
`dyno run --sim --web` at phone and desktop widths (mid-test, then after a drill's abort) and `dyno serve`.

    python bench/web_screenshots.py [--out docs/img]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PHONE, DESKTOP = {"width": 390, "height": 844}, {"width": 1280, "height": 900}


def start(args, cwd, env):
    p = subprocess.Popen([sys.executable, "-m", "dyno", *map(str, args)], cwd=cwd, env=env, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    url = []
    ready = threading.Event()

    def read():
        for line in p.stderr:
            m = re.match(r"web: (\S+)", line)
            if m and not url:
                url.append(m.group(1))
                ready.set()
    threading.Thread(target=read, daemon=True).start()
    if not ready.wait(120):
        raise SystemExit("no web: line")
    return p, url[0]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "img")
    a = ap.parse_args()
    from playwright.sync_api import sync_playwright

    a.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        env = dict(os.environ, PYTHONPATH=str(REPO), DYNO_RUNS_DIR=tmp)
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=["--no-sandbox"])
        run, url = start(["run", "--sim", "--headless", "--speed", "6", "--drill", "overtemp@100", "--out",
                          Path(tmp) / "shop-run", "--web"], tmp, env)
        phone = browser.new_page(viewport=PHONE, device_scale_factor=2)
        desk = browser.new_page(viewport=DESKTOP)
        for page in (phone, desk):
            page.goto(url)
        desk.wait_for_function("document.querySelectorAll('#points tbody tr').length >= 4", timeout=180_000)
        time.sleep(1.0)
        desk.screenshot(path=a.out / "web-live-desktop.png", full_page=True)
        phone.screenshot(path=a.out / "web-live-phone.png")
        phone.wait_for_selector("#banner:not([hidden])", timeout=180_000)
        phone.wait_for_function("document.getElementById('rig-safe').dataset.safe === 'true'", timeout=60_000)
        phone.screenshot(path=a.out / "web-live-phone-abort.png")
        run.wait(120)
        serve, surl = start(["serve", tmp], tmp, env)
        try:
            desk.goto(surl)
            desk.screenshot(path=a.out / "web-serve-desktop.png")
        finally:
            serve.terminate()
            serve.wait(20)
        browser.close()
    for p in sorted(a.out.glob("web-*.png")):
        print(p, p.stat().st_size)
    return 0


if __name__ == "__main__":
    sys.exit(main())
