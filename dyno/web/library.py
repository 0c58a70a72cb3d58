"""``dyno serve``: the run library in a browser — runs filtered by tune, date and state, each run's
report.html, its files and points to download, two or more runs compared (``dyno compare``'s page).

Read-only: nothing here writes into a run (the compare page and points.csv are made in memory; the index
is brought up to date as ``dyno runs`` does).  A run is named by its path under the runs directory and
must be one the index lists; a file by a bare name in the run directory or its ``export/`` folder.  A
``..`` segment, an encoded slash (``%2f``) or anything that resolves outside the run is refused (400/404).
"""

from __future__ import annotations

import asyncio
import csv
import html
import io
import re
import urllib.parse
from pathlib import Path

from aiohttp import web

from dyno.web.server import TOKEN_COOKIE, WebServer
from dyno.web.live import static_file

E = html.escape
STATES = ("", "done", "aborted", "incomplete", "success", "abort")
POINT_FIELDS = ("index", "rpm_primary", "rpm_secondary", "ratio", "torque_secondary_nm", "power_out_w", "power_in_w",
                "efficiency", "efficiency_sem", "efficiency_ci95", "efficiency_u95", "valid")
DATE = re.compile(r"\d{4}-\d{2}-\d{2}")


class Library:
    def __init__(self, root: Path) -> None:
        self.root = Path(root).resolve()

    # --- the index, in a worker thread (SQLite and the directory scan never run on the server's loop) --------
    def _rows(self, tune=None, since=None, state=None) -> list[dict]:
        from dyno.library import index as lib

        conn = lib.open_library(self.root)
        try:
            lib.sync(conn, self.root)
            rows = lib.query(conn, tune=tune or None, since=since or None, state=state or None)
        finally:
            conn.close()
        for r in rows:
            r["rel"] = self.rel(r["path"])
        return [r for r in rows if r["rel"] is not None]

    def rel(self, path: str) -> str | None:
        try:
            return Path(path).resolve().relative_to(self.root).as_posix()
        except ValueError:
            return None

    async def rows(self, **filters) -> list[dict]:
        return await asyncio.get_running_loop().run_in_executor(None, lambda: self._rows(**filters))

    async def run_dir(self, rel: str) -> Path:
        """The run directory the index knows by ``rel``; 400 for a traversal attempt, 404 for no such run."""
        parts = rel.split("/")
        if not rel or any(p in ("", ".", "..") or "\\" in p or "\x00" in p for p in parts):
            raise web.HTTPBadRequest(text="400: not a run name (no '..', no empty or hidden segments)\n")
        known = {r["rel"]: r["path"] for r in await self.rows()}
        if rel not in known:
            raise web.HTTPNotFound(text=f"404: no run {rel!r} in {self.root}\n")
        d = Path(known[rel]).resolve()
        if not d.is_relative_to(self.root):
            raise web.HTTPForbidden(text="403: outside the runs directory\n")
        return d

    # --- routes -------------------------------------------------------------------------------------------
    def make_app(self, server: WebServer) -> web.Application:
        app = web.Application(middlewares=[refuse_encoded_slashes])
        app.router.add_get("/", self.index)
        app.router.add_get("/api/runs", self.api_runs)
        app.router.add_get("/compare", self.compare)
        app.router.add_get("/static/{name}", static_file)
        app.router.add_get("/runs/{tail:.+}", self.run_file)
        return app

    async def api_runs(self, request: web.Request) -> web.Response:
        rows = await self.rows(**_filters(request))
        for r in rows:
            r.pop("files_sig", None)
        return web.json_response({"root": str(self.root), "runs": rows})

    async def index(self, request: web.Request) -> web.Response:
        f = _filters(request)
        rows = await self.rows(**f)
        token = request.query.get("token", "")
        tq = _q(token)
        opts = "".join(f"<option{' selected' if s == f['state'] else ''}>{E(s)}</option>" for s in STATES)
        out = [_head("dyno — runs", tq), f"<header><h1>dyno <span class=sub>run library · {E(str(self.root))}</span>"
               "</h1></header><div class=lib>",
               f"<form method=get action='/'><input type=hidden name=token value='{E(token)}'>"
               f"<label>tune <input name=tune value='{E(f['tune'] or '')}' size=14></label>"
               f"<label>since <input name=since type=date value='{E(f['since'] or '')}'></label>"
               f"<label>state <select name=state>{opts}</select></label><button>filter</button></form>",
               f"<form method=get action='/compare'><input type=hidden name=token value='{E(token)}'>"
               f"<p><span id=count>{len(rows)}</span> runs. Tick two or more and <button>compare</button> "
               "(the first ticked is the reference).</p><div class=scroll><table id=runs><thead><tr><th></th>"
               "<th>created (UTC)</th><th>run</th><th>tune</th><th>state</th><th>abort</th><th>points</th>"
               "<th>peak eff %</th><th>files</th></tr></thead><tbody>"]
        for r in reversed(rows):  # newest first
            rel = r["rel"]
            base = "/runs/" + urllib.parse.quote(rel)
            eff = "" if r["peak_efficiency"] is None else f"{100 * r['peak_efficiency']:.1f}"
            out.append(f"<tr data-run='{E(rel)}'><td><input type=checkbox name=run value='{E(rel)}'></td>"
                       f"<td>{E(r['created_utc'] or '')}</td><td><a class=report href='{base}/report.html{tq}'>"
                       f"{E(rel)}</a></td><td>{E(r['tune_name'] or '')}</td><td class=state>{E(r['state'] or '')}</td>"
                       f"<td>{E(r['abort_cause'] or '')}</td><td>{r['n_points'] or 0}</td><td>{eff}</td>"
                       f"<td><a href='{base}/points.csv{tq}'>points.csv</a> · <a href='{base}/files{tq}'>files</a>"
                       "</td></tr>")
        out.append("</tbody></table></div></form></div></body></html>")
        resp = web.Response(text="".join(out), content_type="text/html")
        if token:
            resp.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite="Strict")
        return resp

    async def run_file(self, request: web.Request) -> web.StreamResponse:
        tail = request.match_info["tail"]
        for suffix in ("/report.html", "/points.csv", "/files"):
            if tail.endswith(suffix):
                run = await self.run_dir(tail[: -len(suffix)])
                return await getattr(self, "_" + suffix[1:].replace(".", "_"))(request, run)
        rel, sep, name = tail.partition("/files/")
        if not sep:
            raise web.HTTPNotFound(text="404: /runs/RUN/report.html, /runs/RUN/points.csv, /runs/RUN/files[/NAME]\n")
        run = await self.run_dir(rel)
        return self._file(run, name)

    async def _report_html(self, request, run: Path) -> web.Response:
        path = run / "report.html"
        if not path.is_file():
            raise web.HTTPNotFound(text=f"404: {run.name} has no report.html yet (`dyno report {run}` writes it)\n")
        return web.Response(body=path.read_bytes(), content_type="text/html")

    async def _points_csv(self, request, run: Path) -> web.Response:
        from dyno.library.summary import read_run_files

        files = await asyncio.get_running_loop().run_in_executor(None, read_run_files, run)
        buf = io.StringIO()
        w = csv.DictWriter(buf, POINT_FIELDS, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        for d in files["documents"]:
            if d.get("type") == "point":
                w.writerow({k: d.get(k) for k in POINT_FIELDS})
        return web.Response(text=buf.getvalue(), content_type="text/csv", headers={
            "Content-Disposition": f'attachment; filename="{_safe_name(run.name)}-points.csv"'})

    async def _files(self, request, run: Path) -> web.Response:
        tq = _q(request.query.get("token", ""))
        base = "/runs/" + urllib.parse.quote(self.rel(str(run)))
        items = []
        for name in downloadable(run):
            size = (run / name).stat().st_size
            items.append(f"<li><a href='{base}/files/{urllib.parse.quote(name)}{tq}'>{E(name)}</a> "
                         f"<span class=muted>{size:,} bytes</span></li>")
        body = (f"{_head('dyno — ' + run.name, tq)}<div class=lib><h1>{E(run.name)}: files</h1>"
                f"<p><a href='/{tq}'>all runs</a> · <a href='{base}/report.html{tq}'>report</a> · "
                f"<a href='{base}/points.csv{tq}'>points.csv</a></p><ul id=files>{''.join(items)}</ul>"
                "<p class='muted small'>Parquet / MDF4: <code>dyno export RUN --format parquet|mdf4</code> on the "
                "rig's computer writes them into the run's export/ folder, listed here.</p></div></body></html>")
        return web.Response(text=body, content_type="text/html")

    def _file(self, run: Path, name: str) -> web.FileResponse:
        if name not in downloadable(run):  # only the names listed: nothing else is reachable
            raise web.HTTPNotFound(text="404: no such file in this run\n")
        path = (run / name).resolve()
        if not path.is_relative_to(run):
            raise web.HTTPForbidden(text="403: outside the run directory\n")
        return web.FileResponse(path, headers={
            "Content-Disposition": f'attachment; filename="{_safe_name(Path(name).name)}"'})

    async def compare(self, request: web.Request) -> web.Response:
        rels = request.query.getall("run", [])
        if len(rels) < 2:
            raise web.HTTPBadRequest(text="400: compare needs two or more runs (?run=A&run=B...)\n")
        dirs = [await self.run_dir(r) for r in rels]
        try:
            page = await asyncio.get_running_loop().run_in_executor(None, compare_page, dirs)
        except ValueError as exc:
            raise web.HTTPUnprocessableEntity(text=f"422: these runs cannot be compared: {exc}\n") from None
        return web.Response(text=page, content_type="text/html")


def compare_page(dirs: list[Path]) -> str:
    """``dyno compare``'s HTML page, in memory (nothing written)."""
    from dyno.library.compare import compare
    from dyno.library.compare_html import render
    from dyno.library.index import key
    from dyno.library.summary import read_run_files, run_row

    runs = []
    for d in dirs:  # (as dyno compare loads them)
        files = read_run_files(d)
        runs.append({"name": d.name, "row": run_row(files, key(d)),
                     "points": [x for x in files["documents"] if x.get("type") == "point"],
                     "tune": files["tune"]["data"] if files["tune"] else None, "meta": files["meta"]})
    names = [r["name"] for r in runs]
    for i, n in enumerate(names):
        if names.count(n) > 1:
            runs[i]["name"] = f"{n} ({dirs[i].parent.name})"
    return render(compare(runs))


def downloadable(run: Path) -> list[str]:
    """The run's regular files and those of its export/ folder (relative names), nothing hidden, no links."""
    out = []
    for folder in (run, run / "export"):
        if not folder.is_dir() or folder.is_symlink():
            continue
        for p in sorted(folder.iterdir()):
            if p.name.startswith(".") or p.is_symlink() or not p.is_file():
                continue
            out.append(p.relative_to(run).as_posix())
    return out


@web.middleware
async def refuse_encoded_slashes(request: web.Request, handler):
    """An encoded slash or dot segment in the raw path is a traversal attempt: 400, before any routing."""
    raw = request.raw_path.split("?", 1)[0].lower()
    if "%2f" in raw or "%5c" in raw or "%2e%2e" in raw or "/../" in raw + "/" or "\\" in raw:
        raise web.HTTPBadRequest(text="400: encoded slashes and '..' are refused\n")
    return await handler(request)


def _filters(request: web.Request) -> dict:
    q = request.query
    since = q.get("since", "").strip()
    state = q.get("state", "").strip()
    if since and not DATE.fullmatch(since):
        raise web.HTTPBadRequest(text=f"400: since: expected a date YYYY-MM-DD, got {since!r}\n")
    if state not in STATES:
        raise web.HTTPBadRequest(text=f"400: state: expected one of {', '.join(s for s in STATES if s)}\n")
    return {"tune": q.get("tune", "").strip() or None, "since": since or None, "state": state or None}


def _q(token: str) -> str:
    return f"?token={urllib.parse.quote(token)}" if token else ""


def _safe_name(name: str) -> str:
    return re.sub(r"[^\w.-]", "_", name)


def _head(title: str, tq: str) -> str:
    return (f"<!doctype html><html lang=en><head><meta charset=utf-8><meta name=viewport "
            f"content='width=device-width, initial-scale=1'><title>{E(title)}</title>"
            f"<link rel=stylesheet href='/static/style.css{tq}'></head><body>")


def start_library_server(root: Path, bind: str | None) -> WebServer:
    from dyno.web.server import parse_bind

    host, port = parse_bind(bind)
    server = WebServer(Library(root).make_app, host, port)
    server.start()
    return server


__all__ = ["Library", "start_library_server"]
