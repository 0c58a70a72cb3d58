"""Reads a run directory, tolerating a run that was killed mid-write."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from dyno.acquisition.streams import Streams
from dyno.errors import ConfigError
from dyno.protocol.v1 import Event
from dyno.runlog.writer import EVENT_RECORD


@dataclass
class Run:
    path: Path
    meta: dict
    documents: list
    streams: Streams
    calibration: dict | None
    engine_map_path: Path | None
    torn: dict = field(default_factory=dict)

    def docs(self, doc_type: str) -> list:
        return [d for d in self.documents if d.get("type") == doc_type]

    @property
    def points(self) -> list:
        return self.docs("point")

    @property
    def stop(self) -> dict | None:
        s = self.docs("stop")
        return s[-1] if s else None


def load_run(run_dir, *, with_events: bool = True) -> Run:
    """The run in ``run_dir``; ``with_events=False`` skips ``events.bin`` (the report needs only documents)."""
    run_dir = Path(run_dir)
    meta_path = run_dir / "meta.json"
    if not meta_path.is_file():
        raise ConfigError(run_dir, "meta.json", "a run directory written by dyno (meta.json missing)")
    try:
        meta = json.loads(meta_path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError:
        raise ConfigError(meta_path, "file", "UTF-8 JSON text") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(meta_path, f"line {exc.lineno}", "valid JSON") from exc
    if not isinstance(meta, dict):
        raise ConfigError(meta_path, "top level", f"a JSON object, got {type(meta).__name__}")
    torn = {}
    documents = []
    docs_path = run_dir / "documents.jsonl"
    if docs_path.exists():
        try:
            lines = docs_path.read_bytes().decode("utf-8").split("\n")
        except UnicodeDecodeError as exc:
            raise ConfigError(docs_path, f"byte {exc.start}", "UTF-8 text, one JSON document per line") from None
        for i, line in enumerate(lines):
            if not line.strip():
                continue
            try:
                documents.append(json.loads(line))
            except json.JSONDecodeError as exc:
                if i >= len(lines) - 2:  # the last line, torn by a kill
                    torn["documents"] = line[:80]
                    continue
                raise ConfigError(docs_path, f"line {i + 1}", "one JSON document per line") from exc
    streams = Streams()
    ev_path = run_dir / "events.bin"
    if with_events and ev_path.exists():
        raw = ev_path.read_bytes()
        size = EVENT_RECORD.size
        whole = len(raw) - len(raw) % size
        if whole != len(raw):
            torn["events_bytes"] = len(raw) - whole
        streams.extend(Event(*rec) for rec in EVENT_RECORD.iter_unpack(raw[:whole]))
    cal_path = run_dir / "calibration.json"
    calibration = json.loads(cal_path.read_text()) if cal_path.exists() else None
    map_path = run_dir / "engine_map.csv"
    return Run(run_dir, meta, documents, streams, calibration, map_path if map_path.exists() else None, torn)
