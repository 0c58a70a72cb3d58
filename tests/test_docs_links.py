"""Every relative link in README.md and docs/ (measurement logs included) points at a file that exists.

Reference docs link the dated measurement logs where they quote a figure (docs/measurements/); a log moved or
renamed without its links is caught here.  Links inside code spans and fenced blocks are not links."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.M | re.S)
CODE_SPAN = re.compile(r"`[^`\n]*`")


def doc_files() -> list[Path]:
    return [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]


def relative_links(text: str) -> list[str]:
    text = CODE_SPAN.sub("", FENCE.sub("", text))
    out = []
    for target in LINK.findall(text):
        if re.match(r"[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("#"):
            continue  # http:, mailto:, in-page anchors
        out.append(target.split("#", 1)[0])
    return out


@pytest.mark.quick
def test_relative_links_found_by_the_pattern():
    """The pattern sees links and images, not code spans or URLs (else the check below checks nothing)."""
    text = "see [a](x/y.md#sec) and ![i](img/p.png \"t\"), `[c](nope.md)`, [u](https://e.org), [h](#top)\n" \
           "```\n[f](fenced.md)\n```\n"
    assert relative_links(text) == ["x/y.md", "img/p.png"]
    assert REPO_PATH.findall("(docs/measurements/2026-11-28-x.md, `hardware/rig.toml`; ../hardware/README.md)") == \
        ["docs/measurements/2026-11-28-x.md", "hardware/rig.toml"]


@pytest.mark.quick
@pytest.mark.parametrize("doc", doc_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_resolves(doc: Path):
    broken = [t for t in relative_links(doc.read_text(encoding="utf-8"))
              if not (doc.parent / t).resolve().exists()]
    assert not broken, f"{doc.relative_to(REPO)}: links to missing files: {broken}"


REPO_PATH = re.compile(r"(?<![\w/.-])(docs/[\w./-]+\.(?:md|png|svg)|hardware/[\w./-]+\.(?:md|toml))")


@pytest.mark.quick
@pytest.mark.parametrize("doc", doc_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_every_docs_path_named_in_the_text_exists(doc: Path):
    """The docs also name each other by path from the repository root ("docs/measurements/…md",
    "hardware/README.md"), in prose and code spans: those must exist too."""
    named = set(REPO_PATH.findall(doc.read_text(encoding="utf-8")))
    missing = sorted(p for p in named if not (REPO / p).exists())
    assert not missing, f"{doc.relative_to(REPO)}: names missing files: {missing}"
