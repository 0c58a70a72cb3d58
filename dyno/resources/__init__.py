"""The files the program reads by default: rig files (``hardware/``), calibration (``calibration/``) and the
prebuilt firmware (``firmware/build/``, when built: ``make -C firmware release``).

They are the repository's own folders, shipped in the wheel as ``dyno.resources.hardware`` and
``dyno.resources.calibration`` (setup.py maps the folders; nothing is copied into the tree, so the two
cannot drift).  An installed wheel reads them through :mod:`importlib.resources`; a source checkout or an
editable install, where this package holds no data, reads the repository's folders themselves.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

_REPO = Path(__file__).resolve().parents[2]
FOLDERS = ("hardware", "calibration")  # the repository folders shipped as dyno.resources.<name>, editable copies
#: every shipped folder and where it is in the repository (firmware: `make -C firmware release`'s output)
SOURCES = {"hardware": "hardware", "calibration": "calibration", "firmware": "firmware/build"}


def resource(relative: str) -> Path:
    """The shipped file ``relative`` (e.g. ``"hardware/rig.toml"``) as a path on disk.

    A wheel's files are on disk already (pip unpacks it), so the path stays valid for the process.
    """
    top, _, rest = relative.partition("/")
    if top not in SOURCES:
        raise ValueError(f"{relative}: not under {', '.join(SOURCES)}")
    packaged = Path(str(resources.files(__name__).joinpath(relative)))
    if packaged.exists():
        return packaged
    return _REPO / SOURCES[top] / rest


def packaged_root(folder: str) -> Path:
    """The shipped folder ``hardware`` or ``calibration`` (whole, for ``dyno init``)."""
    return resource(folder)


#: the shipped calibration history and the representative engine map: a run's defaults (dyno.session.root), the
#: fake rig's (dyno.control.fake_rig)
DEFAULT_CALIBRATION = resource("calibration/torque_calibration.csv")
DEFAULT_ENGINE_MAP = resource("calibration/engine_maps/baja-10hp-representative.csv")
