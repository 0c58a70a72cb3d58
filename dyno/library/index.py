"""The run library's index: one SQLite file (WAL) in the runs directory.

The run directories stay the source of truth: the index only caches what
:mod:`dyno.library.summary` derives from their small files, so it can be deleted
or found corrupt at any time and is rebuilt from them (:func:`open_library` does
that itself, reporting one line).  Runs written outside the runs directory
(``--out``) are indexed by their absolute path and kept on a rebuild while they
still exist.
"""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

from dyno.library.summary import (POINT_COLUMNS, RUN_COLUMNS, files_signature, point_rows, read_run_files,
                                  run_row)

INDEX_NAME = "library.sqlite"
SCHEMA_VERSION = 1  # bump when a column changes: an index of another version is rebuilt


class IndexUnusable(Exception):
    """The index file is not a usable index of this version (it is rebuilt)."""


def runs_dir() -> Path:
    """The runs directory: ``$DYNO_RUNS_DIR``, else the state directory's ``runs`` (:func:`runs_root`)."""
    from dyno.runlog.files import runs_root

    return runs_root()


def key(run_dir) -> str:
    return str(Path(run_dir).resolve())


def _create(conn: sqlite3.Connection) -> None:
    """Create the tables; idempotent, in one write transaction (two runs may end at once)."""
    cols = ", ".join(f"{n} {t}" for n, t in RUN_COLUMNS)
    pcols = ", ".join(f"{n} {t}" for n, t in POINT_COLUMNS)
    conn.execute("BEGIN IMMEDIATE")
    try:
        for stmt in (f"CREATE TABLE IF NOT EXISTS runs ({cols})",
                     f"CREATE TABLE IF NOT EXISTS points ({pcols}, PRIMARY KEY (run_path, idx))",
                     "CREATE INDEX IF NOT EXISTS runs_tune ON runs (tune_name)",
                     "CREATE INDEX IF NOT EXISTS runs_created ON runs (created_utc)",
                     f"PRAGMA user_version = {SCHEMA_VERSION}"):
            conn.execute(stmt)
        conn.commit()
    except BaseException:
        conn.rollback()
        raise


def connect(db_path: Path) -> sqlite3.Connection:
    """Open (creating if absent) an index; IndexUnusable/sqlite3.DatabaseError if it is not one."""
    conn = sqlite3.connect(db_path, timeout=15.0)
    try:
        conn.row_factory = sqlite3.Row
        conn.execute("PRAGMA journal_mode=WAL")  # readers never block the run that is being indexed
        version = conn.execute("PRAGMA user_version").fetchone()[0]
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if version == 0 and not tables:
            _create(conn)
        elif version != SCHEMA_VERSION or not {"runs", "points"} <= tables:
            raise IndexUnusable(f"schema version {version}, expected {SCHEMA_VERSION}")
        else:
            check = conn.execute("PRAGMA quick_check").fetchone()[0]
            if check != "ok":
                raise IndexUnusable(f"integrity check: {check}")
            names = [r[1] for r in conn.execute("PRAGMA table_info(runs)")]
            if names != [n for n, _ in RUN_COLUMNS]:
                raise IndexUnusable("the runs table has other columns")
    except BaseException:
        conn.close()
        raise
    return conn


def _remove(db_path: Path) -> None:
    for suffix in ("", "-wal", "-shm"):
        try:
            os.unlink(f"{db_path}{suffix}")
        except FileNotFoundError:
            pass


def _locked_retry(fn, attempts: int = 20):
    """Call ``fn``, retrying while SQLite says "database is locked".

    SQLite returns that at once, without its busy timeout, where waiting could deadlock
    (two fresh connections switching a new file to WAL, or upgrading a read to a write):
    two runs ending together hit it.  A short randomised back-off then succeeds.
    """
    import random
    import time

    for k in range(attempts):
        try:
            return fn()
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or k == attempts - 1:
                raise
            time.sleep(0.01 + random.random() * 0.05 * (k + 1))


def open_library(root=None, warn=None) -> sqlite3.Connection:
    """The index of the runs directory ``root``, rebuilt from the run directories if unusable.

    ``warn(line)`` gets one line when the index had to be rebuilt.  An index that cannot
    be opened or written at all (a busy one past the timeout, a read-only directory) is
    a ConfigError, never deleted.
    """
    from dyno.errors import ConfigError

    root = Path(root) if root is not None else runs_dir()
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(root, "runs directory", f"a directory dyno can create and write ({exc.strerror})") from None
    db_path = root / INDEX_NAME
    try:
        return _locked_retry(lambda: connect(db_path))
    except sqlite3.OperationalError as exc:  # busy, read-only, cannot open: not broken
        raise ConfigError(db_path, "run index", f"an index dyno can open and write ({exc})") from None
    except (sqlite3.DatabaseError, IndexUnusable) as exc:
        if warn is not None:
            warn(f"{db_path}: not a usable run index ({exc}): rebuilt from the run directories in {root}")
        _remove(db_path)
        conn = connect(db_path)
        reindex(conn, root)
        return conn


def find_run_dirs(root: Path) -> list[Path]:
    """Every run directory (one with ``meta.json``) under ``root``, not looking inside runs."""
    found = []
    stack = [Path(root)]
    while stack:
        d = stack.pop()
        if (d / "meta.json").is_file():
            found.append(d)
            continue
        try:
            with os.scandir(d) as it:
                stack.extend(Path(e.path) for e in it if e.is_dir(follow_symlinks=False))
        except OSError:
            continue
    return sorted(found)


def _write_run(conn: sqlite3.Connection, run_dir: Path) -> None:
    path_key = key(run_dir)
    files = read_run_files(run_dir)
    row = run_row(files, path_key, files_signature(run_dir))
    conn.execute("DELETE FROM points WHERE run_path = ?", (path_key,))
    conn.execute(f"INSERT OR REPLACE INTO runs ({', '.join(row)}) VALUES ({', '.join('?' * len(row))})",
                 tuple(row.values()))
    pts = point_rows(files, path_key)
    if pts:
        names = [n for n, _ in POINT_COLUMNS]
        conn.executemany(f"INSERT OR REPLACE INTO points ({', '.join(names)}) VALUES ({', '.join('?' * len(names))})",
                         [tuple(p[n] for n in names) for p in pts])


def index_run(conn: sqlite3.Connection, run_dir) -> None:
    """Add or refresh one run (ConfigError if ``run_dir`` is not a run directory)."""
    def write():
        with conn:
            _write_run(conn, Path(run_dir))

    _locked_retry(write)


def reindex(conn: sqlite3.Connection, root) -> int:
    """Rebuild the whole index from the run directories under ``root`` (plus outside runs that still exist)."""
    from dyno.errors import ConfigError

    root = Path(root)
    inside = find_run_dirs(root)
    keys = {key(d) for d in inside}
    outside = [Path(r[0]) for r in conn.execute("SELECT path FROM runs")
               if r[0] not in keys and (Path(r[0]) / "meta.json").is_file()]
    n = 0
    with conn:
        conn.execute("DELETE FROM points")
        conn.execute("DELETE FROM runs")
        for d in sorted(set(inside) | set(outside)):
            try:
                _write_run(conn, d)
                n += 1
            except (ConfigError, OSError):
                continue  # not a readable run: the listing simply does not show it
    return n


def sync(conn: sqlite3.Connection, root) -> int:
    """Index the runs under ``root`` that are new or changed; drop rows whose directory is gone."""
    from dyno.errors import ConfigError

    known = {r[0]: r[1] for r in conn.execute("SELECT path, files_sig FROM runs")}
    changed = 0
    with conn:
        for d in find_run_dirs(Path(root)):
            k = key(d)
            if known.get(k) != files_signature(d):
                try:
                    _write_run(conn, d)
                    changed += 1
                except (ConfigError, OSError):
                    continue
        for k in known:
            if not (Path(k) / "meta.json").is_file():
                conn.execute("DELETE FROM points WHERE run_path = ?", (k,))
                conn.execute("DELETE FROM runs WHERE path = ?", (k,))
                changed += 1
    return changed


def query(conn: sqlite3.Connection, *, tune: str | None = None, since: str | None = None,
          state: str | None = None) -> list[dict]:
    """Runs, oldest first, filtered by tune name (or tune sha256 prefix), date >= since, state."""
    where, args = [], []
    if tune:
        where.append("(tune_name = ? OR tune_sha256 LIKE ?)")
        args += [tune, f"{tune}%"]
    if since:
        where.append("date >= ?")
        args.append(since)
    if state:
        where.append("(state = ? OR exit_status = ?)")
        args += [state, state]
    sql = "SELECT * FROM runs" + (" WHERE " + " AND ".join(where) if where else "") + " ORDER BY created_utc, path"
    return [dict(r) for r in conn.execute(sql, args)]


def points_of(conn: sqlite3.Connection, path_key: str) -> list[dict]:
    return [dict(r) for r in conn.execute("SELECT * FROM points WHERE run_path = ? ORDER BY idx", (path_key,))]


def dump(conn: sqlite3.Connection) -> dict:
    """Every row of both tables, ordered (to compare two indexes)."""
    return {"runs": [dict(r) for r in conn.execute("SELECT * FROM runs ORDER BY path")],
            "points": [dict(r) for r in conn.execute("SELECT * FROM points ORDER BY run_path, idx")]}


def index_after_run(run_dir, warn) -> bool:
    """The end-of-run hook: index ``run_dir`` in the runs directory's library.

    ``run_dir=None``: the run went to the runs directory under a name the caller does
    not know (``dyno ui``): index whatever is new there.  Never raises: a failure is one
    line to ``warn`` (the run itself is on disk and ``dyno runs reindex`` picks it up later).
    """
    try:
        conn = open_library(warn=warn)
        try:
            if run_dir is None:
                _locked_retry(lambda: sync(conn, runs_dir()))
            else:
                index_run(conn, run_dir)
        finally:
            conn.close()
        return True
    except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 - indexing must never change how a run ends
        warn(f"run library: {run_dir or runs_dir()} not indexed ({type(exc).__name__}: {exc}); "
             "`dyno runs reindex` retries")
        return False
