"""rig.toml: the driven side's inertia has one source, [inertia]; an old file's [driven] inertia keys still
load (mapped, one deprecation line each) or, when they contradict [inertia], name their field."""

import copy
import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from dyno.errors import ConfigError
from dyno.rig.config import DEFAULT_RIG_PATH, rig_from_dict

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

ROOT = Path(__file__).resolve().parents[2]
OLD_DRIVEN = {"inertia_kg_m2": 0.0251, "inertia_rel_unc": 0.03, "inertia_beyond_gauge_kg_m2": 0.0121}


@pytest.fixture(scope="module")
def base():
    with open(DEFAULT_RIG_PATH, "rb") as fh:
        return tomllib.load(fh)


def _old(base, **driven):
    """The rig file as it was before: the inertia keys in [driven], [inertia] without them."""
    d = copy.deepcopy(base)
    for k in ("beyond_gauge_kg_m2", "driven_rel_unc"):
        d["inertia"].pop(k)
    d["driven"] = {**OLD_DRIVEN, **driven}
    return d


def test_shipped_file_says_it_once(base):
    rig = rig_from_dict(base, "rig.toml")
    assert rig.deprecations == () and "inertia_kg_m2" not in base.get("driven", {})
    assert rig.inertia.driven_kg_m2 == pytest.approx(0.0251) and rig.inertia.driven_rel_unc == 0.03
    assert rig.inertia.beyond_gauge_kg_m2 == 0.0121 and rig.inertia.secondary_kg_m2 == 0.013


def test_old_file_loads_the_same_values_with_a_line_per_key(base):
    new, old = rig_from_dict(base, "rig.toml"), rig_from_dict(_old(base), "old.toml")
    assert old.inertia == new.inertia and old.driven == new.driven
    assert len(old.deprecations) == 3 and all(line.startswith("old.toml: [driven] inertia") and "\n" not in line
                                              for line in old.deprecations)


def test_old_total_without_the_upstream_part_sets_it(base):
    d = _old(base, inertia_kg_m2=0.0300)
    d["inertia"].pop("secondary_kg_m2")
    rig = rig_from_dict(d, "old.toml")
    assert rig.inertia.secondary_kg_m2 == pytest.approx(0.0300 - 0.0121)
    assert rig.inertia.driven_kg_m2 == pytest.approx(0.0300)
    assert any("secondary_kg_m2 = 0.0179 mapped" in line for line in rig.deprecations)


@pytest.mark.parametrize("driven, inertia, field", [
    ({"inertia_kg_m2": 0.0300}, {}, "driven.inertia_kg_m2"),  # the whole != the parts: which is right?
    ({"inertia_rel_unc": 0.05}, {"driven_rel_unc": 0.03}, "driven.inertia_rel_unc"),  # said twice, differently
    ({"inertia_beyond_gauge_kg_m2": -1.0}, {}, "driven.inertia_beyond_gauge_kg_m2"),
])
def test_contradictions_name_their_field(base, driven, inertia, field):
    d = _old(base, **driven)
    d["inertia"].update(inertia)
    with pytest.raises(ConfigError) as exc:
        rig_from_dict(d, "bad.toml")
    assert exc.value.field == field and "\n" not in str(exc.value)


def _dump(d: dict) -> str:
    """A minimal TOML writer for the rig file's shapes (tables of scalars and of tables)."""
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)

    lines, tables = [], []

    def walk(prefix, t):
        scalars = [(k, v) for k, v in t.items() if not isinstance(v, dict)]
        if prefix:
            lines.append(f"[{prefix}]")
        lines.extend(f"{k} = {val(v)}" for k, v in scalars)
        for k, v in t.items():
            if isinstance(v, dict):
                tables.append((f"{prefix}.{k}" if prefix else k, v))

    walk("", d)
    while tables:
        walk(*tables.pop(0))
    return "\n".join(lines) + "\n"


def test_old_file_as_a_real_process(tmp_path, base):
    """`dyno run --rig OLD --plan coast-down`: runs, one warning line per old key (not repeated), and the
    coast-down uses the mapped inertia; a contradicting file: one line naming the field, exit 2, no run."""
    old = tmp_path / "old.toml"
    old.write_text(_dump(_old(base)))
    assert tomllib.loads(old.read_text()) == _old(base)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "dyno", "run", "--sim", "--json", "--plan", "coast-down"]
    proc = subprocess.run([*cmd, "--rig", str(old), "--out", str(tmp_path / "run")], capture_output=True, text=True, timeout=120,
                          cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr
    warned = [ln for ln in proc.stderr.splitlines() if "deprecated" in ln]
    assert len(warned) == 3 and all(ln.startswith(f"dyno: warning: {old}: [driven] inertia") for ln in warned)
    d = json.loads(proc.stdout)
    assert d["state"] == "done" and d["loss_fit"]["inertia_kg_m2"] == pytest.approx(0.0251)
    bad = tmp_path / "bad.toml"
    bad.write_text(_dump(_old(base, inertia_kg_m2=0.03)))
    proc = subprocess.run([*cmd, "--rig", str(bad), "--out", str(tmp_path / "bad_run")], capture_output=True, text=True, timeout=120,
                          cwd=tmp_path, env=env)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "driven.inertia_kg_m2" in proc.stderr, proc.stderr
    assert not (tmp_path / "bad_run").exists()
