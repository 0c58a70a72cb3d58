"""Wiring faults the rig's own code found, kept across runs until ``dyno doctor --toggle`` clears them.

An end switch found stuck in one session is still stuck in the next: a new ``dyno`` process must not trust it
again just because it forgot.  :class:`dyno.hw.rig.HardwareRig` (the real pins only; never a mock factory)
writes the faults its driver found when it closes and hands the standing ones to the next driver
(``GpioActuators(known_faults=...)``: the switch starts untrusted, every release runs its full stroke, GO and
re-arm are refused); ``dyno doctor --toggle``, once the switch reads closed at the stop and open a step out,
clears the file.

The file: ``rig_faults.json`` in the state directory (:func:`dyno.datapaths.state_dir`), one for the service and
the operator: ``hardware/dyno.service`` sets ``DYNO_STATE_DIR=/var/lib/dyno`` (its ``StateDirectory``, group
``dyno``); unset, ``/var/lib/dyno`` where that directory exists, else the user's data directory.  A
JSON list of the fault records, each ``{"channel", "detail", "t_s", ...}`` as the driver made it, plus
``recorded_unix_s``.

A file that cannot be read or is corrupt does not forget: the faults it kept are unknown, so :func:`load` gives a
standing fault for every channel the file keeps (:data:`CHANNELS`), naming the file; ``dyno doctor --toggle``'s
pass clears it and rewrites the file.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from dyno.datapaths import state_dir


#: the channels whose faults the file keeps (the driver's wiring faults: dyno.hw.endswitch)
CHANNELS = ("end_switch",)
def state_path() -> Path:
    return state_dir() / "rig_faults.json"


def load(path: Path | None = None) -> list[dict]:
    """The standing faults ([] when there is no file); an unreadable or corrupt file is itself a standing fault
    on every channel it keeps (module doc)."""
    p = path or state_path()
    try:
        data = json.loads(p.read_text())
    except FileNotFoundError:
        return []
    except (OSError, ValueError) as exc:  # (UnicodeDecodeError is a ValueError)
        return _unknown(p, f"{type(exc).__name__}: {exc}")
    if not isinstance(data, list) or not all(isinstance(f, dict) and isinstance(f.get("channel"), str)
                                             for f in data):
        return _unknown(p, "not a list of fault records")
    return data


def _unknown(p: Path, why: str) -> list[dict]:
    detail = (f"unknown: the standing-fault file {p} cannot be read ({why}), so the faults it kept are not known; "
              "check the switch and its wire, then `dyno doctor --toggle`")
    return [{"channel": ch, "detail": detail, "t_s": None, "from_file": str(p), "file_unreadable": True}
            for ch in CHANNELS]


def record(faults: list[dict], path: Path | None = None) -> None:
    """Add ``faults`` to the standing ones (one per channel: the first kept)."""
    if not faults:
        return
    p = path or state_path()
    standing = load(p)
    have = {f["channel"] for f in standing}
    for f in faults:
        if f.get("channel") not in have:
            standing.append({**f, "recorded_unix_s": time.time()})
            have.add(f.get("channel"))
    _write(p, standing)


def clear(channel: str, path: Path | None = None) -> bool:
    """Forget the standing fault of ``channel`` (an unreadable file's too: it is rewritten); True if there was
    one.  OSError if the file cannot be rewritten (the fault then stands)."""
    p = path or state_path()
    standing = load(p)
    keep = [f for f in standing if f.get("channel") != channel]
    if len(keep) == len(standing):
        return False
    if keep:
        _write(p, keep)
    elif p.is_dir():  # (a directory where the file belongs: the unreadable file it was)
        p.rmdir()
    else:
        p.unlink(missing_ok=True)
    return True


def _write(p: Path, faults: list[dict]) -> None:
    """Atomically, through a temporary file of this process's own (the service and the operator share the
    directory: neither may meet the other's half-written file or its leftover)."""
    import tempfile

    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".rig_faults.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(faults, indent=1))
        os.chmod(tmp, 0o664)  # the group (dyno) reads and replaces it
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
