"""The web server: aiohttp on its own asyncio loop in its own thread (never the rig's loop).

:class:`WebServer` serves a :class:`aiohttp.web.Application` built by a caller (the live view,
:mod:`dyno.web.live`; the run library, :mod:`dyno.web.library`) behind the access token: every request
carries it as the ``token`` query parameter (or the ``dyno_token`` cookie the page sets), else 401.
An error inside a handler is a bare status, never a traceback (one line on stderr).
"""

from __future__ import annotations

import asyncio
import hmac
import secrets
import sys
import threading
from pathlib import Path

from aiohttp import web

TOKEN_COOKIE = "dyno_token"
STATIC = Path(__file__).resolve().parent / "static"


def parse_bind(text: str | None, default_port: int = 0) -> tuple[str, int]:
    """``ADDR:PORT``, ``ADDR`` or ``:PORT`` (or None: 127.0.0.1, port ``default_port``); ValueError names it."""
    if text is None or text == "":
        return "127.0.0.1", default_port
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = text, str(default_port)
    host = host.strip("[]") or "127.0.0.1"
    try:
        p = int(port)
    except ValueError:
        p = -1
    if not 0 <= p <= 65535:
        raise ValueError(f"expected ADDR:PORT with a port 0..65535 (0: a free one), got {text!r}")
    return host, p


def new_token() -> str:
    return secrets.token_urlsafe(16)


def token_middleware(token: str):
    @web.middleware
    async def check(request: web.Request, handler):
        given = request.query.get("token") or request.cookies.get(TOKEN_COOKIE) or ""
        if not hmac.compare_digest(given.encode(), token.encode()):
            return web.Response(status=401, text="401: the access token is missing or wrong (use the URL the "
                                                 "dyno command printed: .../?token=...)\n")
        try:
            return await handler(request)
        except web.HTTPException:
            raise
        except (ConnectionResetError, asyncio.CancelledError):
            raise
        except Exception as exc:  # noqa: BLE001  a status, never a traceback
            print(f"dyno web: {request.method} {request.path}: {type(exc).__name__}: {exc}", file=sys.stderr)
            return web.Response(status=500, text="500: internal error (logged on the server's stderr)\n")
    return check


def secure_headers(resp: web.StreamResponse) -> None:
    resp.headers.setdefault("X-Content-Type-Options", "nosniff")
    resp.headers.setdefault("Referrer-Policy", "no-referrer")  # the token is in the URL
    resp.headers.setdefault("Cache-Control", "no-store")


class WebServer:
    """``make_app(loop) -> web.Application`` is called on the server's own loop, in its thread."""

    def __init__(self, make_app, host: str = "127.0.0.1", port: int = 0, token: str | None = None) -> None:
        self.make_app = make_app
        self.host, self.port = host, port
        self.token = token or new_token()
        self.loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stop: asyncio.Event | None = None
        self.on_stop: list = []  # coroutines functions run on the server's loop before it closes

    @property
    def url(self) -> str:
        host = self.host if self.host not in ("0.0.0.0", "::", "") else _this_host()
        if ":" in host:
            host = f"[{host}]"
        return f"http://{host}:{self.port}/?token={self.token}"

    def start(self, timeout_s: float = 10.0) -> str:
        """Bind and serve; returns the URL. A bind failure raises OSError here (the caller's one line)."""
        self._thread = threading.Thread(target=self._main, name="dyno-web", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise OSError(f"the web server did not start within {timeout_s:g} s")
        if self._error is not None:
            raise self._error
        return self.url

    def _main(self) -> None:
        loop = self.loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # noqa: BLE001  reported to start()'s caller
            self._error = exc
            self._ready.set()
        finally:
            loop.close()

    async def _serve(self) -> None:
        self._stop = asyncio.Event()
        app = self.make_app(self)
        app.middlewares.insert(0, token_middleware(self.token))
        app.on_response_prepare.append(lambda req, resp: _prepare(resp))
        runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=0.5)
        await runner.setup()
        site = web.TCPSite(runner, self.host, self.port, reuse_address=True)
        await site.start()
        self.port = runner.addresses[0][1]
        self._ready.set()
        try:
            await self._stop.wait()
        finally:
            for fn in self.on_stop:
                try:
                    await fn()
                except Exception:  # noqa: BLE001
                    pass
            await runner.cleanup()

    def stop(self, timeout_s: float = 2.0) -> None:
        if self.loop is not None and self._stop is not None and not self.loop.is_closed():
            try:
                self.loop.call_soon_threadsafe(self._stop.set)
            except RuntimeError:  # closed in the meantime
                pass
        if self._thread is not None:
            self._thread.join(timeout_s)


async def _prepare(resp) -> None:
    secure_headers(resp)


def _this_host() -> str:
    """The name a phone on the shop network can reach this machine by (its first address)."""
    import socket

    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("192.0.2.1", 9))  # (no packet is sent: picks the outgoing interface)
            return s.getsockname()[0]
    except OSError:
        return socket.gethostname()
