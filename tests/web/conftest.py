"""The web pages' tests: real `dyno` processes, a real browser (Playwright driving Debian's chromium)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CHROMIUM = "/usr/bin/chromium"


def _missing() -> str | None:
    try:
        import aiohttp  # noqa: F401
        import playwright.sync_api  # noqa: F401
    except ImportError as exc:
        return f"{exc.name} is not installed (pip install -e '.[web,webtest]'; .ci/run does)"
    if not Path(CHROMIUM).exists():
        return f"{CHROMIUM} is missing (apt-get install chromium fonts-dejavu-core; .ci/run does)"
    return None


MISSING = _missing()
needs_browser = pytest.mark.skipif(MISSING is not None, reason=MISSING or "")


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"], headless=True)
        yield b
        b.close()


class DynoProcess:
    """One `dyno` command as a user starts it; :attr:`url` from its `web: ...` line on stderr."""

    def __init__(self, args, cwd: Path, env: dict | None = None, stdout=subprocess.PIPE) -> None:
        e = dict(os.environ)
        e["PYTHONPATH"] = str(REPO)  # this tree
        e.update(env or {})
        self.proc = subprocess.Popen([sys.executable, "-m", "dyno", *map(str, args)], cwd=cwd, env=e,
                                     stdout=stdout, stderr=subprocess.PIPE, text=True)
        self.stderr_lines: list[str] = []
        self._url = threading.Event()
        self.url = None
        self._out: list[str] = []
        threading.Thread(target=self._read_err, daemon=True).start()
        if stdout is subprocess.PIPE:
            threading.Thread(target=lambda: self._out.append(self.proc.stdout.read()), daemon=True).start()

    def _read_err(self) -> None:
        for line in self.proc.stderr:
            self.stderr_lines.append(line)
            m = re.match(r"web: (http://\S+)", line)
            if m and self.url is None:
                self.url = m.group(1)
                self._url.set()

    def wait_url(self, timeout_s: float = 60) -> str:
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end and not self._url.wait(0.2):
            assert self.proc.poll() is None, f"exited {self.proc.returncode}: {''.join(self.stderr_lines)}"
        assert self.url, f"no 'web: URL' line on stderr: {''.join(self.stderr_lines)}"
        return self.url

    @property
    def base(self) -> str:
        return self.url.split("/?token=")[0]

    @property
    def token(self) -> str:
        return self.url.split("token=")[1]

    def wait(self, timeout_s: float = 120) -> int:
        rc = self.proc.wait(timeout_s)
        time.sleep(0.1)
        return rc

    @property
    def stdout(self) -> str:
        return "".join(self._out)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def http_status(url: str, method: str = "GET") -> tuple[int, str]:
    req = urllib.request.Request(url, method=method)
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read().decode(errors="replace")
    except urllib.error.HTTPError as e:
        return e.code, e.read(2000).decode(errors="replace")


needs_tmux = pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")


class DroppingProxy:
    """A TCP forwarder between the browser and a server whose connections the test can cut (a network drop):
    :meth:`drop` closes every open connection and refuses new ones for ``down_s``."""

    def __init__(self, host: str, port: int) -> None:
        import socket

        self.upstream = (host, port)
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.down_until = 0.0
        self.pairs: list = []
        self.accepted = 0
        self._lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        import socket

        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            if time.monotonic() < self.down_until:
                client.close()  # the network is down
                continue
            try:
                server = socket.create_connection(self.upstream)
            except OSError:
                client.close()
                continue
            self.accepted += 1
            with self._lock:
                self.pairs.append((client, server))
            for a, b in ((client, server), (server, client)):
                threading.Thread(target=self._pipe, args=(a, b), daemon=True).start()

    @staticmethod
    def _pipe(a, b) -> None:
        import socket

        try:
            while data := a.recv(65536):
                b.sendall(data)
        except OSError:
            pass
        for s in (a, b):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def drop(self, down_s: float) -> None:
        import socket

        self.down_until = time.monotonic() + down_s
        with self._lock:
            pairs, self.pairs = self.pairs, []
        for pair in pairs:
            for s in pair:
                try:
                    s.shutdown(socket.SHUT_RDWR)
                    s.close()
                except OSError:
                    pass

    def close(self) -> None:
        self.drop(0)
        self.listener.close()
