"""dyno serve: the run library in a browser (read-only): runs by tune, date, state; reports; compare; downloads."""

from __future__ import annotations

import sys
from pathlib import Path


def add_arguments(p) -> None:
    p.add_argument("dir", nargs="?", type=Path, default=None, metavar="RUNS_DIR",
                   help="the runs directory (default: $DYNO_RUNS_DIR, else runs/)")
    p.add_argument("--bind", default=None, metavar="ADDR:PORT",
                   help="where to serve (default 127.0.0.1 and a free port; give an address to serve the shop "
                        "network); the URL with its access token is printed on stderr as 'web: ...' (docs/web.md)")


def run(args) -> int:
    from dyno.errors import ConfigError
    from dyno.library.index import runs_dir

    root = args.dir if args.dir is not None else runs_dir()
    if not Path(root).is_dir():
        raise ConfigError(root, "RUNS_DIR", "an existing runs directory")
    try:
        from dyno.web.library import start_library_server
    except ImportError as exc:
        print(f"dyno serve: needs the web extra ({exc.name} missing): pip install -e '.[web]'", file=sys.stderr)
        return 2
    try:
        server = start_library_server(Path(root), args.bind)
    except ValueError as exc:
        print(f"dyno serve: --bind: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"dyno serve: --bind {args.bind or '127.0.0.1:0'}: cannot serve there: {exc.strerror or exc}",
              file=sys.stderr)
        return 2
    print(f"web: {server.url}", file=sys.stderr, flush=True)
    print(f"dyno serve: the run library in {Path(root).resolve()}; Ctrl+C ends", file=sys.stderr, flush=True)
    try:
        while server._thread.is_alive():
            server._thread.join(0.5)
    finally:
        server.stop()
    return 0
