"""Layers one way (docs/architecture.md): the faces below the command line do not import it, and the report
and the web view do not reach into the terminal UI for what they share (that lives in the layers below).

Read with tokenize (not ast: a module's source is enough, and nothing is imported)."""

import io
import tokenize
from pathlib import Path

import pytest

DYNO = Path(__file__).resolve().parents[1] / "dyno"


def imported_modules(path: Path) -> set[str]:
    """Every ``dyno...`` module named after ``import`` or ``from`` in ``path`` (top level or in a function)."""
    names, toks = set(), list(tokenize.generate_tokens(io.StringIO(path.read_text()).readline))
    for i, t in enumerate(toks):
        if t.type == tokenize.NAME and t.string in ("import", "from") and i + 1 < len(toks):
            j, parts = i + 1, []
            while j < len(toks) and (toks[j].type == tokenize.NAME or toks[j].string == "."):
                if toks[j].string in ("import", "as"):
                    break
                parts.append(toks[j].string)
                j += 1
            name = "".join(parts)
            if name.startswith("dyno"):
                names.add(name)
    return names


# (package, packages it must not import)
RULES = [("dyno/ui", ("dyno.cli",)), ("dyno/web", ("dyno.cli", "dyno.ui")), ("dyno/report", ("dyno.cli", "dyno.ui")),
         ("dyno/model", ("dyno.cli", "dyno.ui", "dyno.web", "dyno.report")),
         ("dyno/control", ("dyno.cli", "dyno.ui", "dyno.web", "dyno.report"))]


@pytest.mark.quick
@pytest.mark.parametrize("package, forbidden", RULES)
def test_no_upward_import(package, forbidden):
    bad = [f"{p.relative_to(DYNO.parent)}: {m}" for p in sorted((DYNO.parent / package).rglob("*.py"))
           for m in sorted(imported_modules(p)) if m.startswith(forbidden)]
    assert not bad, "imports against the layers:\n" + "\n".join(bad)


def test_the_reader_sees_function_level_imports(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import os\nfrom dyno.a import b\n\ndef g():\n    from dyno.cli.progress import eta_now\n")
    assert imported_modules(f) == {"dyno.a", "dyno.cli.progress"}
