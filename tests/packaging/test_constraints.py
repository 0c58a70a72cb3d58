"""constraints.txt pins every package the project's requirements bring in (issue 53: the versions CI ran)."""

from __future__ import annotations

import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

REPO = Path(__file__).resolve().parents[2]
EXTRAS = ("test", "export", "web", "webtest", "cluster")  # what .ci/run installs


def pins() -> dict[str, str]:
    out = {}
    for line in (REPO / "constraints.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"constraints.txt: {line!r}: not an exact pin (name==version)"
            out[canonicalize_name(name)] = version
    return out


def required_closure() -> set[str]:
    """The project's requirements (with CI's extras) and, through the installed packages, theirs."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    todo = [(Requirement(r), "") for r in project["dependencies"]]
    todo += [(Requirement(r), e) for e in EXTRAS for r in project["optional-dependencies"][e]]
    seen: set[str] = set()
    while todo:
        req, extra = todo.pop()
        if req.marker is not None and not req.marker.evaluate({"extra": extra}):
            continue
        name = canonicalize_name(req.name)
        if name in seen:
            continue
        seen.add(name)
        try:
            dist = metadata.distribution(req.name)
        except metadata.PackageNotFoundError:
            continue  # (not installed here: its own requirements cannot be read; its pin is still checked)
        for sub in dist.requires or []:
            for e in ("", *req.extras):
                todo.append((Requirement(sub), e))
    return seen


@pytest.mark.quick
def test_every_required_package_is_pinned_to_what_is_installed():
    pinned = pins()
    needed = required_closure()
    assert {"numpy", "textual", "pytest", "aiohttp", "dask"} <= needed  # (the walk reaches the extras)
    missing = sorted(needed - set(pinned))
    assert not missing, f"constraints.txt has no pin for {missing}"
    for name in needed:
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
        assert installed == pinned[name], f"{name}: constraints.txt says {pinned[name]}, this venv has {installed}"
