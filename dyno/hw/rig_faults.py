"""Wiring faults the rig's own code found, kept across runs until ``dyno doctor --toggle`` clears them.

An end switch found stuck in one session is still stuck in the next: a new ``dyno`` process must not trust it
again just because it forgot.  :class:`dyno.hw.rig.HardwareRig` (the real pins only; never a mock factory)
writes the faults its driver found when it closes and hands the standing ones to the next driver
(``GpioActuators(known_faults=...)``: the switch starts untrusted, every release runs its full stroke, GO and
re-arm are refused); ``dyno doctor --toggle``, once the switch reads closed at the stop and open a step out,
clears the file.

The file: ``$DYNO_STATE_DIR/rig_faults.json``, else ``~/.local/state/dyno/rig_faults.json`` (a JSON list of
the fault records, each ``{"channel", "detail", "t_s", ...}`` as the driver made it, plus ``recorded_unix_s``).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path


def state_path() -> Path:
    base = os.environ.get("DYNO_STATE_DIR")
    root = Path(base) if base else Path.home() / ".local" / "state" / "dyno"
    return root / "rig_faults.json"


def load(path: Path | None = None) -> list[dict]:
    """The standing faults ([] when none, or when the file is unreadable: it then says so on the next write)."""
    p = path or state_path()
    try:
        data = json.loads(p.read_text())
    except (OSError, ValueError):
        return []
    return [f for f in data if isinstance(f, dict) and "channel" in f] if isinstance(data, list) else []


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
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_suffix(".tmp")
    tmp.write_text(json.dumps(standing, indent=1))
    os.replace(tmp, p)


def clear(channel: str, path: Path | None = None) -> bool:
    """Forget the standing fault of ``channel``; True if there was one."""
    p = path or state_path()
    standing = load(p)
    keep = [f for f in standing if f.get("channel") != channel]
    if len(keep) == len(standing):
        return False
    if keep:
        p.write_text(json.dumps(keep, indent=1))
    else:
        p.unlink(missing_ok=True)
    return True
