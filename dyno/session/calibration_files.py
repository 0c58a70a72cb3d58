"""Which calibration history a run reads and where ``dyno calibrate`` appends: the state directory's copy.

The package ships a history (``calibration/torque_calibration.csv``, and the engine-side channel's); the
package is never written to.  The rig's own history lives in the state directory
(:func:`dyno.datapaths.state_dir` ``/calibration/``): a run reads it once it exists, else the shipped one;
the first calibration on the rig starts it from the shipped entries, so the history stays one file.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from dyno.datapaths import state_dir
from dyno.resources import resource

TORQUE_HISTORY = "torque_calibration.csv"


def state_history(name: str = TORQUE_HISTORY) -> Path:
    """The state directory's history file ``name`` (it may not exist yet)."""
    return state_dir() / "calibration" / Path(name).name


def calibration_in_force(name: str = TORQUE_HISTORY) -> Path:
    """The history a run reads: the state directory's, else the shipped one."""
    mine = state_history(name)
    return mine if mine.is_file() else resource(f"calibration/{Path(name).name}")


def history_to_append(name: str = TORQUE_HISTORY) -> Path:
    """The state directory's history, started from the shipped entries when it does not exist yet."""
    mine = state_history(name)
    if not mine.is_file():
        mine.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(resource(f"calibration/{Path(name).name}"), mine)
    return mine


def is_shipped(path: Path) -> bool:
    """``path`` is one of the shipped calibration files (the package's, never appended to)."""
    shipped = resource(f"calibration/{Path(path).name}")
    return shipped.exists() and Path(path).resolve() == shipped.resolve()
