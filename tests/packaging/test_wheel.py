"""The wheel is the program (issue 53): built from this tree, installed into a fresh virtual environment, it runs
the main job from an empty directory, reading its rig file and calibration from inside the package and writing
only to the state directory.

Not quick (a wheel build and a simulated run).  Offline-safe: the fresh venv gets the project's dependencies by a
path to this venv's site-packages (a ``.pth`` line: a plain path, so this venv's editable ``dyno`` finder is not
loaded), and the wheel itself is installed with ``--no-deps``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _build_wheel(out: Path) -> Path:
    """``pip wheel`` of the repository: isolated (setuptools from pip's cache or the index), else this venv's."""
    base = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(REPO)]
    r = subprocess.run(base, capture_output=True, text=True, timeout=600)
    if r.returncode != 0:  # no index and nothing cached: this venv's setuptools, if new enough
        r = subprocess.run(base + ["--no-build-isolation"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    wheels = sorted(out.glob("dyno-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


def _fresh_venv(where: Path, wheel: Path) -> Path:
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(where)], check=True, timeout=300)
    py = where / "bin" / "python"
    site = Path(subprocess.run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    # the dependencies (numpy, scipy, textual, ...) from this venv, after the fresh venv's own site-packages
    (site / "zz_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                        "--target", str(site), str(wheel)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    # the console script as pip writes it for an installed wheel
    dyno = where / "bin" / "dyno"
    dyno.write_text(f"#!{py}\nimport sys\nfrom dyno.cli import main\nsys.exit(main())\n")
    dyno.chmod(0o755)
    return dyno


def _env(tmp: Path) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("DYNO_RIG", "DYNO_RUNS_DIR", "PYTHONPATH", "VIRTUAL_ENV", "XDG_DATA_HOME")}
    env["DYNO_MODEL_CACHE"] = os.environ.get("DYNO_MODEL_CACHE") or str(Path.home() / ".cache" / "dyno" / "model")
    env["HOME"] = str(tmp / "home")  # no ~/.config/dyno/rig.toml of this machine's user
    env["DYNO_STATE_DIR"] = str(tmp / "state")
    return env


def test_the_installed_wheel_runs_the_main_job_from_an_empty_directory(tmp_path):
    with_firmware = shutil.which("avr-gcc") is not None
    if with_firmware:  # the prebuilt firmware the wheel ships (`dyno flash`), as CI builds it
        from tests.fw_build import make

        built = make("release", timeout_s=600.0)
        assert built.returncode == 0, built.stdout + built.stderr
    wheel = _build_wheel(tmp_path / "dist")
    names = zipfile.ZipFile(wheel).namelist()
    if with_firmware:
        for shipped in ("dyno/resources/firmware/dyno_nano.hex", "dyno/resources/firmware/dyno_nano_oldboot.hex",
                        "dyno/resources/firmware/firmware.json"):
            assert shipped in names, shipped
        assert not [n for n in names if n.endswith((".o", ".elf", ".a"))]  # the HEX files only, no build tree
    for shipped in ("dyno/resources/hardware/rig.toml", "dyno/resources/calibration/torque_calibration.csv",
                    "dyno/resources/calibration/engine_maps/baja-10hp-representative.csv",
                    "dyno/resources/calibration/tunes/cvtech-stock.toml", "dyno/control/plan_files/speed-hold.toml"):
        assert shipped in names, shipped
    venv = tmp_path / "venv"
    dyno = _fresh_venv(venv, wheel)
    empty = tmp_path / "empty"
    empty.mkdir()
    (tmp_path / "home").mkdir()
    env = _env(tmp_path)
    where = subprocess.run([venv / "bin" / "python", "-c", "import dyno; print(dyno.__file__)"], cwd=empty,
                           env=env, capture_output=True, text=True, check=True).stdout.strip()
    assert Path(where).is_relative_to(venv), where  # the wheel's copy, not this tree
    if with_firmware:
        stamp = subprocess.run([venv / "bin" / "python", "-c", "from dyno.hw.flash import shipped_image as s; "
                                "i = s(); print(i.version, i.protocol, i.files['optiboot'])"], cwd=empty, env=env,
                               capture_output=True, text=True, check=True).stdout.split()
        config_h = (REPO / "firmware" / "src" / "config.h").read_text()
        version = ".".join(line.split()[2] for line in config_h.splitlines()
                           if line.startswith("#define FW_VERSION_") and line.split()[1][-5:] in ("MAJOR", "MINOR", "PATCH"))
        assert stamp[:2] == [version, "2"] and Path(stamp[2]).is_relative_to(venv), stamp

    r = subprocess.run([dyno, "run", "--sim", "--headless", "--json"], cwd=empty, env=env, capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads(r.stdout)
    assert result["state"] == "done"
    assert result["points"], "no steady-state point"
    rig_file = result["rig_file"]
    assert rig_file["found_by"] == "packaged" and Path(rig_file["path"]).is_relative_to(venv), rig_file
    assert f"rig file {rig_file['path']} (packaged)" in r.stderr
    assert Path(result["run_dir"]).is_relative_to(tmp_path / "state"), result["run_dir"]
    meta = json.loads((Path(result["run_dir"]) / "meta.json").read_text())
    assert Path(meta["calibration_source"]).is_relative_to(venv)  # the shipped history, read from the package
    assert list(empty.iterdir()) == []  # nothing written where it ran

    # real hardware never runs on the shipped rig file: one line, exit 2, before any pin is touched
    d = subprocess.run([dyno, "doctor"], cwd=empty, env=env, capture_output=True, text=True, timeout=300)
    assert d.returncode == 2 and "Traceback" not in d.stderr
    assert len(d.stderr.strip().splitlines()) == 1 and "--sim only" in d.stderr, d.stderr

    # dyno init: editable copies, then found where the search looks first (after --rig and $DYNO_RIG)
    i = subprocess.run([dyno, "init"], cwd=empty, env=env, capture_output=True, text=True, timeout=300)
    assert i.returncode == 0, i.stderr
    assert (empty / "hardware" / "rig.toml").read_bytes() == (REPO / "hardware" / "rig.toml").read_bytes()
    again = subprocess.run([dyno, "init"], cwd=empty, env=env, capture_output=True, text=True, timeout=300)
    assert again.returncode == 2 and len(again.stderr.strip().splitlines()) == 1 and "exists" in again.stderr
