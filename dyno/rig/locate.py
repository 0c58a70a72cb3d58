"""Which rig file a command reads: the search order, and the refusal to drive real hardware from the shipped one.

``--rig PATH``, else ``$DYNO_RIG``, else ``./hardware/rig.toml`` (a folder made by ``dyno init`` or the
repository), else ``~/.config/dyno/rig.toml``, else ``/etc/dyno/rig.toml``, else the rig file shipped in the
package.  The shipped file describes the thesis rig for the simulator: its pins are never guessed onto a
real rig, so a command that touches hardware refuses it (:func:`require_own_rig`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from dyno.errors import ConfigError
from dyno.resources import resource

RIG_ENV = "DYNO_RIG"  # the systemd unit may point it at /etc/dyno/rig.toml
PACKAGED = "packaged"  # how the shipped default was found (the JSON's ``rig_file.found_by``)


@dataclass(frozen=True)
class RigFile:
    """A rig file and how it was found: ``--rig``, ``$DYNO_RIG``, the searched location, or ``packaged``."""

    path: Path
    found_by: str

    def to_dict(self) -> dict:
        return {"path": str(self.path), "found_by": self.found_by}

    def line(self) -> str:
        return f"rig file {self.path} ({self.found_by})"


def packaged_rig() -> Path:
    """The rig file shipped in the package (the simulator's thesis rig)."""
    return resource("hardware/rig.toml")


def search_path() -> list[tuple[Path, str]]:
    """The places searched after ``--rig`` and ``$DYNO_RIG``, in order, each with its name."""
    return [(Path("hardware") / "rig.toml", "./hardware/rig.toml"),
            (Path.home() / ".config" / "dyno" / "rig.toml", "~/.config/dyno/rig.toml"),
            (Path("/etc/dyno/rig.toml"), "/etc/dyno/rig.toml")]


def find_rig(path: str | Path | None = None) -> RigFile:
    """The rig file a command reads (module docstring's order); a given path is used as is, found or not."""
    if path is not None:
        return RigFile(Path(path), "--rig")
    env = os.environ.get(RIG_ENV)
    if env:
        return RigFile(Path(env), f"${RIG_ENV}")
    for candidate, name in search_path():
        if candidate.is_file():
            return RigFile(candidate.resolve(), name)
    return RigFile(packaged_rig(), PACKAGED)


def require_own_rig(found: RigFile) -> None:
    """Refuse real hardware described by the shipped rig file: one line (exit 2), wrong pins never guessed."""
    if found.found_by == PACKAGED:
        raise ConfigError(found.path, "file", "the shipped rig file serves --sim only; a real rig needs its own: "
                          "`dyno init` writes an editable copy to ./hardware/rig.toml (or use --rig, $DYNO_RIG, "
                          "~/.config/dyno/rig.toml, /etc/dyno/rig.toml)")



def add_rig_argument(parser) -> None:
    """``--rig PATH`` for any command; load it with ``load_rig(args.rig)`` (or ``load_rig_for`` on hardware)."""
    parser.add_argument(
        "--rig", metavar="PATH", default=None,
        help=f"rig description (default: ${RIG_ENV}, ./hardware/rig.toml, ~/.config/dyno/rig.toml, "
             "/etc/dyno/rig.toml, else the shipped one, --sim only)",
    )
