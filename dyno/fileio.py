"""Atomic file replacement, shared by the run log and the calibration history.

Readers see the old content or the new, never half: write a temp file in the
same directory, fsync it, ``os.replace`` it over the target, then fsync the
directory so the rename itself survives a power cut.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def _default_mode(path: Path) -> int:
    """The mode a plain ``open()`` would give: the old file's, else 0666 less the umask.

    (``mkstemp`` creates 0600: a run's files would be unreadable to the rest of the team.)
    """
    try:
        return path.stat().st_mode & 0o777
    except OSError:
        pass
    umask = os.umask(0o022)
    os.umask(umask)
    return 0o666 & ~umask


def write_atomic(path, data: bytes | str, mode: int | None = None) -> None:
    path = Path(path)
    if mode is None:
        mode = _default_mode(path)
    raw = data.encode() if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(raw)
            f.flush()
            os.fsync(f.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    try:  # best effort on filesystems that cannot fsync a directory
        dfd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)
