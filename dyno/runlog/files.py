"""Small file primitives: atomic replace and append-only writes."""

from __future__ import annotations

import json
from pathlib import Path

from dyno.fileio import write_atomic  # noqa: F401  (re-exported for the run log)


def write_json_atomic(path: Path, obj) -> None:
    write_atomic(path, json.dumps(obj, indent=2, sort_keys=True, default=_jsonable) + "\n")


def _jsonable(x):
    import numpy as np

    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def dumps(obj) -> str:
    return json.dumps(obj, sort_keys=True, default=_jsonable, allow_nan=True)
