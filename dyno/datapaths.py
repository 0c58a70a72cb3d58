"""Where data lives: the thesis rig's 2019 logs (read in place, never copied into the repository) and the state
directory the program writes to (:func:`state_dir`).

``$DYNO_LEGACY_DATA`` names the folder (the one holding ``cal_values.csv``, ``engine_power_RPM.csv`` and the
``2019-04-18_run*`` folders); without it, ``../shared/data/vt-cvt-dyno-2019`` next to the repository.
"""

from __future__ import annotations

import os
from pathlib import Path

LEGACY_DATA_ENV = "DYNO_LEGACY_DATA"
REPO = Path(__file__).resolve().parents[1]
DEFAULT_LEGACY_DATA = REPO.parent / "shared" / "data" / "vt-cvt-dyno-2019"


def legacy_data_dir() -> Path:
    """``$DYNO_LEGACY_DATA``, else ``../shared/data/vt-cvt-dyno-2019`` relative to the repository."""
    env = os.environ.get(LEGACY_DATA_ENV)
    return Path(env).expanduser() if env else DEFAULT_LEGACY_DATA


def legacy_data_missing() -> str | None:
    """Why the thesis logs cannot be used (a skip reason naming the variable), or None when they can."""
    d = legacy_data_dir()
    if d.is_dir():
        return None
    return (f"thesis rig logs not found at {d}: set {LEGACY_DATA_ENV} to the folder holding "
            "cal_values.csv, engine_power_RPM.csv and the 2019-04-18_run* folders")


STATE_DIR_ENV = "DYNO_STATE_DIR"
#: the service's state directory (hardware/dyno.service: StateDirectory=dyno)
SERVICE_STATE_DIR = Path("/var/lib/dyno")


def state_dir() -> Path:
    """Where the program writes what it keeps between runs (calibration history, the run library, standing
    faults), one directory for the service and the operator: ``$DYNO_STATE_DIR`` (hardware/dyno.service sets
    ``/var/lib/dyno``), else ``/var/lib/dyno`` where it exists (a command run by hand on the service's Pi finds
    what the service wrote), else ``$XDG_DATA_HOME/dyno``, else ``~/.local/share/dyno``.

    Not created here: a writer makes the folder it needs (``mkdir(parents=True, exist_ok=True)``).
    """
    env = os.environ.get(STATE_DIR_ENV)
    if env:
        return Path(env).expanduser()
    if SERVICE_STATE_DIR.is_dir():
        return SERVICE_STATE_DIR
    xdg = os.environ.get("XDG_DATA_HOME")
    return (Path(xdg).expanduser() if xdg else Path.home() / ".local" / "share") / "dyno"
