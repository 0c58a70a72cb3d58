"""Overlay cache and the ``dyno model`` command."""

import json

import pytest

from dyno.cli import main
from dyno.model import cache_keys, overlay

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

POINTS = [(1.0, 3400.0, 18.0), (1.3, 3400.0, 18.0)]


def test_closed_form_overlay_and_cache(tmp_path):
    first = overlay.predict_overlay(POINTS, tier="closed_form", cache_dir=tmp_path)
    assert [r["cached"] for r in first] == [False, False]
    assert all(r["converged"] and 0 < r["efficiency"]["overall"] <= 1 for r in first)
    again = overlay.predict_overlay(POINTS, tier="closed_form", cache_dir=tmp_path)
    assert [r["cached"] for r in again] == [True, True]
    assert again[0]["axial_force_n"] == first[0]["axial_force_n"]
    assert len(list(tmp_path.glob("*.json"))) == 2


def test_full_overlay_never_solves_twice(tmp_path, monkeypatch, table_6_1):
    calls = []
    from dyno.model import solution

    def fake_solve(params, op, **kwargs):
        calls.append(op)
        return table_6_1

    monkeypatch.setattr(solution, "solve_point", fake_solve)
    res = overlay.predict_overlay([POINTS[0]], cache_dir=tmp_path)
    assert res[0]["converged"] and not res[0]["cached"]
    assert res[0]["efficiency"] == table_6_1.summary["efficiency"]
    res2 = overlay.predict_overlay([POINTS[0]], cache_dir=tmp_path)
    assert res2[0]["cached"] and len(calls) == 1
    # The key covers the inputs: another speed is another entry.
    overlay.predict_overlay([(1.0, 3000.0, 18.0)], cache_dir=tmp_path)
    assert len(calls) == 2


def test_overlay_env_cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("DYNO_MODEL_CACHE", str(tmp_path / "c"))
    assert cache_keys.default_cache_dir() == tmp_path / "c"
    overlay.predict_overlay(POINTS[:1], tier="closed_form")
    assert list((tmp_path / "c").glob("*.json"))


def test_overlay_rejects_bad_points(tmp_path):
    from dyno.errors import ConfigError

    with pytest.raises(ConfigError):
        overlay.predict_overlay([(1.0, 3400.0)], tier="closed_form", cache_dir=tmp_path)
    with pytest.raises(ConfigError):
        overlay.predict_overlay(POINTS, tier="magic", cache_dir=tmp_path)


def test_cli_point_json_keys(capsys):
    # A loose slip threshold keeps this quick; the default run is the Table 6.1 case.
    rc = main(["model", "point", "--json", "--slip-threshold", "1e-2"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("variant", "converged", "residual_max", "slip_threshold_m_s", "solve_s"):
        assert key in out
    assert set(out["wrap_deg"]) >= {"primary", "secondary"}
    assert set(out["axial_force_n"]) >= {"primary", "secondary"}
    assert set(out["efficiency"]) >= {"speed", "torque", "overall"}
    assert set(out["span_tension_n"]) >= {"tight", "slack"}
    assert out["variant"] == "corrected" and out["converged"] is True


def test_cli_bad_input_exit_2(capsys):
    assert main(["model", "point", "--tier", "closed_form", "--ratio", "-1"]) == 2
    assert "ratio" in capsys.readouterr().err
    assert main(["model", "point", "--slip-threshold", "0"]) == 2


def test_model_import_is_cheap():
    import subprocess
    import sys

    code = "import sys, dyno.model.solution, dyno.model.overlay; print('scipy.integrate' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_cache_key_covers_the_model_code_and_failures_are_retried_after_a_change(tmp_path, monkeypatch):
    from dyno.errors import DidNotConverge
    from dyno.model import solution

    calls = []

    def failing(params, op, **kwargs):
        calls.append(op)
        raise DidNotConverge("stalled")

    monkeypatch.setattr(solution, "solve_point", failing)
    first = overlay.predict_overlay([POINTS[0]], cache_dir=tmp_path)
    assert not first[0]["converged"] and first[0]["state"] == "failed" and len(calls) == 1
    again = overlay.predict_overlay([POINTS[0]], cache_dir=tmp_path)
    assert again[0]["cached"] and len(calls) == 1  # same code: the failure is remembered
    assert len(cache_keys.model_code_hash()) == 64
    monkeypatch.setattr(cache_keys, "model_code_hash", lambda: "0" * 64)  # the model's code changed
    retried = overlay.predict_overlay([POINTS[0]], cache_dir=tmp_path)
    assert not retried[0]["cached"] and len(calls) == 2


def test_model_code_hash_reads_every_model_module():
    from pathlib import Path

    here = Path(overlay.__file__).resolve().parent
    # inverse.py and overlay_inputs.py build a prediction's inputs (they are in the key), not part of it; the
    # studies' task and executor modules only say where and in which order solves run; the overlay's
    # service, worker and cache modules carry a job (point_solve.py holds what decides its numbers)
    plumbing = {"overlay", "overlay_service", "overlay_worker", "cache_keys"}
    on_disk = {p.stem for p in here.glob("*.py")} - {"__init__", "sweep", "studies", "inverse", "overlay_inputs",
                                                      "executor", "study_tasks"} - plumbing
    assert on_disk <= set(cache_keys.MODEL_MODULES), on_disk - set(cache_keys.MODEL_MODULES)
    assert not plumbing & set(cache_keys.MODEL_MODULES)


def test_the_cache_key_follows_the_maths_not_the_plumbing(tmp_path):
    """A line split in the overlay worker keeps every cached cell; a changed solver strategy or equation does not."""
    import shutil
    from pathlib import Path

    from dyno.model.cache_keys import code_hash

    here = Path(overlay.__file__).resolve().parent
    copy = tmp_path / "model"
    shutil.copytree(here, copy, ignore=shutil.ignore_patterns("__pycache__"))
    before = code_hash(copy)
    assert before == cache_keys.model_code_hash()
    for name in ("overlay_worker", "overlay_service", "overlay", "cache_keys"):
        f = copy / f"{name}.py"
        f.write_text(f.read_text() + "\n# a comment, a line split: plumbing\n")
    assert code_hash(copy) == before
    for name in ("point_solve", "equations"):
        f = copy / f"{name}.py"
        f.write_text(f.read_text() + "\n# the maths changed\n")
        assert code_hash(copy) != before
        before = code_hash(copy)
