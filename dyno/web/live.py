"""The live view's routes: the page, ``/api/state`` (JSON), ``/api/events`` (SSE), ``/api/stop``.

Frames come from :class:`dyno.web.feed.LiveFeed`'s bounded queue: one pump task takes each, encodes it
to JSON once and wakes every stream; a stream always sends the newest frame, so a slow browser skips
frames and a stuck one blocks only its own handler (its socket's buffer, bounded by aiohttp's writer).
"""

from __future__ import annotations

import asyncio
import json
import queue
import sys

from aiohttp import web

from dyno.web.server import STATIC, TOKEN_COOKIE, WebServer

PUMP_S = 0.05  # how often the server looks for a new frame (adds at most this to a frame's way to the page)
KEEPALIVE_S = 10.0  # a comment line on a quiet stream: proxies and phones keep the connection


class LiveHub:
    """The newest frame, encoded once, and the streams waiting for the next one."""

    def __init__(self, feed, *, allow_stop: bool = False, model=None) -> None:
        self.feed = feed
        self.allow_stop = allow_stop
        self.model = model  # dyno.web.model_curve.ModelCurve (the belt model beside the points), or None
        self._last_snap: dict | None = None
        self._model_version = None
        self.seq = 0
        self.state_json = b'{"state": "starting", "points": []}'  # (before the rig's first frame)
        self.event_bytes = b""
        self._changed: asyncio.Event | None = None
        self.closing = False
        self.streams = 0
        self.stops = 0

    def make_app(self, server: WebServer) -> web.Application:
        self._changed = asyncio.Event()
        app = web.Application()
        app.router.add_get("/", self.page)
        app.router.add_get("/api/state", self.state)
        app.router.add_get("/api/events", self.events)
        app.router.add_post("/api/stop", self.stop)
        app.router.add_get("/static/{name}", static_file)
        app.on_startup.append(self._start_pump)
        app.on_cleanup.append(self._cancel_pump)
        server.on_stop.append(self._close)
        return app

    async def _start_pump(self, app) -> None:
        self._pump_task = asyncio.get_running_loop().create_task(self._pump())

    async def _cancel_pump(self, app) -> None:
        self._pump_task.cancel()

    async def _pump(self) -> None:
        """Look at the queue every PUMP_S and publish the newest frame.  Polling, not a blocking get: the
        rig's ``put_nowait`` then never wakes a waiting thread (a woken thread asks for the GIL at once; the
        rig's loop would pay for that hand-over on every frame)."""
        frames = self.feed.frames
        while not self.closing:
            snap = None
            while True:
                try:
                    snap = frames.get_nowait()
                except queue.Empty:
                    break
                if snap.get("ended"):  # (the last frame is never skipped for a newer one: there is none)
                    break
            if snap is not None:
                await self._with_model(snap)
                self.publish(snap)
            elif self.model is not None and self._last_snap is not None and self.model.version != self._model_version:
                snap = dict(self._last_snap)  # a full-model value arrived (the run may have ended): send again
                await self._with_model(snap)
                self.publish(snap)
            await asyncio.sleep(PUMP_S)

    async def _with_model(self, snap: dict) -> None:
        """The model's part of the frame, worked out in a thread of the server (the inverse of a new point:
        tens of ms; the solves themselves run in the model's own process)."""
        self._last_snap = snap
        if self.model is None:
            return
        try:
            snap["model"] = await asyncio.get_running_loop().run_in_executor(None, self.model.update, snap)
        except Exception as exc:  # noqa: BLE001 - the page's curve must never stop the page
            snap["model"] = {"points": [], "error": f"{type(exc).__name__}: {exc}"}
        self._model_version = self.model.version

    def publish(self, snap: dict) -> None:
        snap["web_stop"] = self.allow_stop
        data = json.dumps(snap, separators=(",", ":"), allow_nan=False, default=str).encode()
        self.seq += 1
        self.state_json = data
        self.event_bytes = b"id: %d\ndata: " % self.seq + data + b"\n\n"
        self._wake()

    def _wake(self) -> None:
        ev, self._changed = self._changed, asyncio.Event()
        ev.set()

    async def _close(self) -> None:
        self.closing = True
        if self.model is not None:
            self.model.close()
        self._wake()

    async def page(self, request: web.Request) -> web.Response:
        token = request.query.get("token", "")
        html = (STATIC / "live.html").read_text().replace("{{Q}}", f"?token={token}" if token else "")
        resp = web.Response(text=html, content_type="text/html")
        if token:
            resp.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite="Strict")
        return resp

    async def state(self, request: web.Request) -> web.Response:
        return web.Response(body=self.state_json, content_type="application/json")

    async def events(self, request: web.Request) -> web.StreamResponse:
        resp = web.StreamResponse(headers={"Content-Type": "text/event-stream", "X-Accel-Buffering": "no"})
        await resp.prepare(request)
        self.streams += 1
        try:
            await resp.write(b"retry: 1000\n\n")  # the browser reconnects by itself 1 s after a drop
            sent = -1
            while not self.closing:
                if sent == self.seq:
                    try:
                        await asyncio.wait_for(self._changed.wait(), KEEPALIVE_S)
                    except asyncio.TimeoutError:
                        await resp.write(b": keepalive\n\n")
                    continue
                sent = self.seq
                await resp.write(self.event_bytes)
            await resp.write(b"event: bye\ndata: {}\n\n")  # the process ends: the page stops retrying
        except (ConnectionResetError, ConnectionError):
            pass
        finally:
            self.streams -= 1
        return resp

    async def stop(self, request: web.Request) -> web.Response:
        if not self.allow_stop:
            return web.Response(status=403, text="403: STOP is off (start the command with --web-stop)\n")
        ok = self.feed.request_stop("web page STOP")
        self.stops += 1
        print("dyno web: STOP from the web page (" + (request.remote or "?") + ")", file=sys.stderr)
        return web.json_response({"stop": "sent" if ok else "the run has ended"})


STATIC_TYPES = {".js": "text/javascript", ".css": "text/css", ".html": "text/html", ".svg": "image/svg+xml"}


async def static_file(request: web.Request) -> web.Response:
    """One of the package's own files by its bare name (no directories: nothing else can be named)."""
    name = request.match_info["name"]
    path = STATIC / name
    if "/" in name or "\\" in name or name.startswith(".") or path.suffix not in STATIC_TYPES or not path.is_file():
        raise web.HTTPNotFound(text="404: no such file\n")
    return web.Response(body=path.read_bytes(), content_type=STATIC_TYPES[path.suffix])


def start_live_server(feed, bind: str | None, *, allow_stop: bool = False,
                      model: bool = True) -> tuple[WebServer, LiveHub]:
    """Serve ``feed`` on ``bind`` (ADDR:PORT; default 127.0.0.1, a free port); ValueError/OSError: one line."""
    from dyno.web.server import parse_bind

    host, port = parse_bind(bind)
    from dyno.web.model_curve import ModelCurve

    hub = LiveHub(feed, allow_stop=allow_stop, model=ModelCurve() if model else None)
    server = WebServer(hub.make_app, host, port)
    server.start()
    return server, hub
