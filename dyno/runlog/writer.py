"""Writes a run directory that is valid at every instant (Bluesky-style documents).

Layout::

    RUN/meta.json         run metadata (rig, calibration, engine map, software, protocol), atomic
    RUN/calibration.json  the calibration entry applied, atomic
    RUN/engine_map.csv    a copy of the engine map used, atomic
    RUN/tune.toml         the CVT tune on the rig (flyweights, springs, helix), atomic
    RUN/documents.jsonl   append-only: start, state, point, abort, stop documents
    RUN/events.bin        append-only raw event stream, 12-byte records <B q H B>:
                          channel, unwrapped t_us, ADC code (or v0 device rpm), status

Every append is flushed to the kernel at once, so a SIGKILL loses nothing
already recorded; a record torn by a kill is at the very end and readers drop it.

A write that fails (disk full, I/O error) stops all further writing — what is on
disk stays a valid, readable prefix — and calls ``on_error(exc)`` once: the
composition root turns that into an abort to the safe state (cause ``disk_full``).
"""

from __future__ import annotations

import os
import struct
import time
from pathlib import Path

from dyno import __version__
from dyno.runlog.files import dumps, write_json_atomic
from dyno.fileio import write_atomic

EVENT_RECORD = struct.Struct("<BqHB")
LOCK_NAME = ".dyno-lock"  # present while a process writes the run (see RunWriter)


class RunWriter:
    def __init__(self, run_dir: Path, meta: dict, calibration: dict | None = None,
                 engine_map_text: str | None = None, tune_text: str | None = None,
                 plan_text: str | None = None, on_error=None) -> None:
        from dyno.errors import ConfigError

        self.run_dir = Path(run_dir)
        lock = self.run_dir / LOCK_NAME
        in_use = ConfigError(self.run_dir, "--out", f"a directory no other dyno process is writing ({lock} "
                             "exists; if no dyno runs, the run that held it was killed: choose a new --out)")
        if lock.exists():
            raise in_use
        if self.run_dir.exists() and any(self.run_dir.iterdir()):
            raise ConfigError(self.run_dir, "--out", "an empty or new directory (refusing to overwrite a run)")
        self.run_dir.mkdir(parents=True, exist_ok=True)
        # Claim the directory atomically: of two processes given the same --out, one gets
        # the lock file and the other refuses before writing anything.
        try:
            fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            raise in_use from None
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{os.getpid()}\n")
        self._lock_path = lock
        meta = dict(meta)
        meta.setdefault("software_version", __version__)
        meta.setdefault("created_unix_s", time.time())
        meta.setdefault("format", "dyno-run/1")
        if calibration is not None:
            write_json_atomic(self.run_dir / "calibration.json", calibration)
        if engine_map_text is not None:
            write_atomic(self.run_dir / "engine_map.csv", engine_map_text)
        if tune_text is not None:
            write_atomic(self.run_dir / "tune.toml", tune_text)
        if plan_text is not None:  # the plan file as run (meta.json keeps its canonical form)
            write_atomic(self.run_dir / "plan.toml", plan_text)
        write_json_atomic(self.run_dir / "meta.json", meta)
        self._docs = open(self.run_dir / "documents.jsonl", "a", encoding="utf-8")
        self._events = open(self.run_dir / "events.bin", "ab")
        self._pack = EVENT_RECORD.pack
        self.closed = False
        self.error: OSError | None = None
        self.on_error = on_error  # callable(OSError), once
        self.doc("start", **{k: meta[k] for k in ("software_version", "format") if k in meta})

    def _append(self, f, data) -> None:
        if self.error is not None:
            return
        try:
            f.write(data)
            f.flush()
        except OSError as exc:
            self.error = exc
            if self.on_error is not None:
                self.on_error(exc)

    def events(self, events, now_s: float | None = None) -> None:
        if not events or self.closed:
            return
        pack = self._pack
        self._append(self._events,
                     b"".join(pack(e.channel, e.t_us, e.code & 0xFFFF, e.status & 0xFF) for e in events))

    def doc(self, doc_type: str, **fields) -> None:
        if self.closed:
            return
        fields["type"] = doc_type
        self._append(self._docs, dumps(fields) + "\n")

    def inject_disk_full(self) -> None:
        """Drill ``disk-full``: from now on every write fails as on a full filesystem."""
        self._docs = _FullDisk(self._docs)
        self._events = _FullDisk(self._events)

    def close(self, exit_status: str, reason: str = "", **extra) -> None:
        if self.closed:
            return
        self.doc("stop", exit_status=exit_status, reason=reason, **extra)
        self.closed = True
        for f in (self._docs, self._events):
            try:
                f.close()
            except OSError:
                pass  # a full disk may refuse the final flush too; what is on disk stays readable
        try:
            self._lock_path.unlink()
        except OSError:
            pass


class _FullDisk:
    """A file whose writes fail with ENOSPC (the disk-full drill); closing closes the real file."""

    def __init__(self, inner) -> None:
        self._inner = inner

    def write(self, data):
        import errno
        import os

        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), getattr(self._inner, "name", "?"))

    def flush(self) -> None:
        self._inner.flush()

    def close(self) -> None:
        self._inner.close()
