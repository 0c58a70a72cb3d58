"""``dyno init [DIR]``: editable copies of the shipped rig files and calibration in DIR (default: here).

DIR/hardware/rig.toml is then the rig file of any command run from DIR (dyno.rig.locate's search order);
the shipped copies stay in the package, untouched.  An existing file is never overwritten without --force:
one line naming it, nothing written.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from dyno.errors import ConfigError
from dyno.resources import FOLDERS, packaged_root

SKIP_SUFFIXES = (".py", ".pyc")


def add_arguments(parser) -> None:
    parser.add_argument("dir", nargs="?", default=".", type=Path, metavar="DIR",
                        help="where to write hardware/ and calibration/ (default: the working directory)")
    parser.add_argument("--force", action="store_true", help="overwrite files that exist")


def shipped_files() -> list[tuple[Path, Path]]:
    """(source, path relative to DIR) of every shipped rig and calibration file."""
    out = []
    for folder in FOLDERS:
        root = packaged_root(folder)
        for src in sorted(root.rglob("*")):
            if src.is_file() and src.suffix not in SKIP_SUFFIXES and "__pycache__" not in src.parts:
                out.append((src, Path(folder) / src.relative_to(root)))
    return out


def run(args) -> int:
    target = Path(args.dir)
    if target.exists() and not target.is_dir():
        raise ConfigError(target, "DIR", "a directory (it is a file)")
    files = shipped_files()
    if not args.force:
        there = [rel for _, rel in files if (target / rel).exists()]
        if there:
            raise ConfigError(target / there[0], "file", f"exists ({len(there)} of the {len(files)} files do): "
                              "nothing written; --force overwrites")
    for src, rel in files:
        dest = target / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dest)
    print(f"dyno init: {len(files)} files into {target.resolve()} (hardware/, calibration/); edit "
          f"hardware/rig.toml for this rig: commands run from here read it", file=sys.stderr)
    return 0
