"""The files the program reads by default: rig files (``hardware/``) and calibration (``calibration/``).

They are the repository's own folders, shipped in the wheel as ``dyno.resources.hardware`` and
``dyno.resources.calibration`` (setup.py maps the folders; nothing is copied into the tree, so the two
cannot drift).  An installed wheel reads them through :mod:`importlib.resources`; a source checkout or an
editable install, where this package holds no data, reads the repository's folders themselves.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

_REPO = Path(__file__).resolve().parents[2]
FOLDERS = ("hardware", "calibration")  # the repository folders shipped as dyno.resources.<name>


def resource(relative: str) -> Path:
    """The shipped file ``relative`` (e.g. ``"hardware/rig.toml"``) as a path on disk.

    A wheel's files are on disk already (pip unpacks it), so the path stays valid for the process.
    """
    top = relative.split("/", 1)[0]
    if top not in FOLDERS:
        raise ValueError(f"{relative}: not under {' or '.join(FOLDERS)}")
    packaged = Path(str(resources.files(__name__).joinpath(relative)))
    if packaged.exists():
        return packaged
    return _REPO / relative


def packaged_root(folder: str) -> Path:
    """The shipped folder ``hardware`` or ``calibration`` (whole, for ``dyno init``)."""
    return resource(folder)
