"""Small file primitives: atomic replace and append-only writes."""

from __future__ import annotations

import json
import math
from pathlib import Path

from dyno.fileio import write_atomic


def write_json_atomic(path: Path, obj) -> None:
    write_atomic(path, json.dumps(finite(obj), indent=2, sort_keys=True, default=_jsonable, allow_nan=False) + "\n")


def _jsonable(x):
    import numpy as np

    if isinstance(x, np.generic):
        return finite(x.item())
    if isinstance(x, np.ndarray):
        return finite(x.tolist())
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def finite(obj):
    """JSON-safe copy: NaN and infinities become None (``NaN`` is not JSON; other tools choke on it)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    return obj


def dumps(obj) -> str:
    return json.dumps(finite(obj), sort_keys=True, default=_jsonable, allow_nan=False)


def runs_root() -> Path:
    """Where runs go by default and where the run library lives: ``$DYNO_RUNS_DIR``, else the state directory's
    ``runs`` (:func:`dyno.datapaths.state_dir`)."""
    import os

    from dyno.datapaths import state_dir

    env = os.environ.get("DYNO_RUNS_DIR")
    return Path(env) if env else state_dir() / "runs"
