"""``--web`` for the commands that run the rig (``dyno run``, ``dyno ui``): start the server before the run,
hook the feed to the run's poller when it exists, hand it the run's last frame, stop it at the end."""

from __future__ import annotations

import sys


def add_web_arguments(p) -> None:
    p.add_argument("--web", nargs="?", const="", default=None, metavar="ADDR:PORT",
                   help="serve a read-only live view of the rig in a browser (default 127.0.0.1 and a free port; "
                        "give an address to serve the shop network); the URL with its access token is printed on "
                        "stderr as 'web: http://HOST:PORT/?token=T' (docs/web.md; pip install -e '.[web]')")
    p.add_argument("--web-stop", action="store_true",
                   help="with --web: a STOP button on the page: the E-STOP key's abort (a software stop that only "
                        "makes the rig safer; NOT an emergency stop)")


class WebView:
    """One command's web view: ``start`` (or None after one stderr line), ``attach(source, loop)``, ``end``."""

    def __init__(self, prog: str, bind: str, allow_stop: bool) -> None:
        self.prog, self.bind, self.allow_stop = prog, bind, allow_stop
        self.feed = self.server = self.hub = None

    @classmethod
    def start(cls, prog: str, args) -> "WebView | None":
        if getattr(args, "web_stop", False) and args.web is None:
            print(f"{prog}: --web-stop: only with --web", file=sys.stderr)
            return None
        if args.web is None:
            return None
        view = cls(prog, args.web, bool(args.web_stop))
        return view if view._serve() else None

    def _serve(self) -> bool:
        try:
            from dyno.web.feed import LiveFeed
            from dyno.web.live import start_live_server
        except ImportError as exc:
            print(f"{self.prog}: --web needs the web extra ({exc.name} missing): pip install -e '.[web]'",
                  file=sys.stderr)
            return False
        self.feed = LiveFeed(None)
        try:
            self.server, self.hub = start_live_server(self.feed, self.bind, allow_stop=self.allow_stop)
        except ValueError as exc:
            print(f"{self.prog}: --web: {exc}", file=sys.stderr)
            return False
        except OSError as exc:
            print(f"{self.prog}: --web {self.bind or '127.0.0.1:0'}: cannot serve there: "
                  f"{exc.strerror or exc}", file=sys.stderr)
            return False
        print(f"web: {self.server.url}", file=sys.stderr, flush=True)
        return True

    def attach(self, source, loop) -> None:
        self.feed.source = source
        self.feed.attach(loop)

    def end(self, result: dict | None = None) -> None:
        """The run's last frame (its verdict on the rig's safety), then the server stops (the page says so)."""
        if self.feed is not None and self.feed.source is not None:
            if result is not None:
                self.feed.final(result)
            self.feed.detach()
        if self.server is not None:
            import time

            time.sleep(0.3)  # the last frame reaches the pages before the streams say goodbye
            self.server.stop()
