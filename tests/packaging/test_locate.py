"""Which rig file a command reads and where what it writes goes (issue 53): the search order, the refusal of the
shipped rig file on hardware, the state directory."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from dyno.datapaths import state_dir
from dyno.errors import ConfigError
from dyno.rig import locate
from dyno.rig.config import load_rig_for
from dyno.rig.locate import PACKAGED, find_rig, packaged_rig, require_own_rig
from dyno.session.calibration_files import calibration_in_force, history_to_append

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def nowhere(tmp_path, monkeypatch):
    """An empty working directory, a home without ~/.config/dyno, no $DYNO_RIG."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("DYNO_RIG", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    real = locate.search_path()  # (this machine's /etc/dyno left out: the test is about the order before it)
    monkeypatch.setattr(locate, "search_path", lambda: [(p, n) for p, n in real if not n.startswith("/etc")])
    return tmp_path


@pytest.mark.quick
def test_the_search_order(nowhere, monkeypatch):
    text = packaged_rig().read_text()
    assert find_rig().found_by == PACKAGED and find_rig().path == packaged_rig()
    home = nowhere / "home" / ".config" / "dyno" / "rig.toml"
    home.parent.mkdir(parents=True)
    home.write_text(text)
    assert find_rig().found_by == "~/.config/dyno/rig.toml" and find_rig().path == home
    here = nowhere / "hardware" / "rig.toml"
    here.parent.mkdir()
    here.write_text(text)
    assert find_rig().found_by == "./hardware/rig.toml" and find_rig().path == here.resolve()
    env = nowhere / "env.toml"
    monkeypatch.setenv("DYNO_RIG", str(env))  # given, used as given: a missing file is an error, not skipped
    assert find_rig().path == env and find_rig().found_by == "$DYNO_RIG"
    assert find_rig("x.toml").path == Path("x.toml") and find_rig("x.toml").found_by == "--rig"


@pytest.mark.quick
def test_the_shipped_rig_file_serves_the_simulator_only(nowhere):
    assert load_rig_for(None, sim=True).path == str(packaged_rig())
    with pytest.raises(ConfigError, match="--sim only"):
        load_rig_for(None, sim=False)
    mine = nowhere / "hardware" / "rig.toml"
    mine.parent.mkdir()
    mine.write_text(packaged_rig().read_text())  # the same pins, but a file of this rig's own: its choice
    require_own_rig(find_rig())
    assert load_rig_for(None, sim=False).path == str(mine.resolve())


@pytest.mark.quick
def test_the_doctor_on_hardware_refuses_the_shipped_file_in_one_line(tmp_path):
    if Path("/etc/dyno/rig.toml").exists():
        pytest.skip("this machine has /etc/dyno/rig.toml: a rig file of its own")
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "DYNO_STATE_DIR": str(tmp_path / "state")}
    r = subprocess.run([sys.executable, "-m", "dyno", "doctor"], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "--sim only" in r.stderr and "dyno init" in r.stderr


@pytest.mark.quick
def test_the_state_directory(monkeypatch, tmp_path):
    monkeypatch.setenv("DYNO_STATE_DIR", str(tmp_path / "s"))
    assert state_dir() == tmp_path / "s"
    monkeypatch.delenv("DYNO_STATE_DIR")
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert state_dir() == tmp_path / "xdg" / "dyno"
    monkeypatch.delenv("XDG_DATA_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "h"))
    assert state_dir() == tmp_path / "h" / ".local" / "share" / "dyno"


@pytest.mark.quick
def test_calibration_history_lives_in_the_state_directory(monkeypatch, tmp_path):
    monkeypatch.setenv("DYNO_STATE_DIR", str(tmp_path))
    shipped = calibration_in_force()
    assert shipped.read_bytes() == (REPO / "calibration" / "torque_calibration.csv").read_bytes()
    mine = history_to_append()  # the first calibration on the rig: its history starts from the shipped entries
    assert mine == tmp_path / "calibration" / "torque_calibration.csv" and mine.read_bytes() == shipped.read_bytes()
    with open(mine, "a") as fh:
        fh.write("\n")
    assert calibration_in_force() == mine  # from now on the runs read the rig's own
    assert history_to_append() == mine and mine.read_bytes().endswith(b"\n\n")  # never restarted
    assert shipped.read_bytes() == (REPO / "calibration" / "torque_calibration.csv").read_bytes()


@pytest.mark.quick
def test_only_the_shipped_history_is_redirected_to_the_state_directory(tmp_path, monkeypatch):
    from dyno.session.calibration_files import is_shipped

    monkeypatch.setenv("DYNO_STATE_DIR", str(tmp_path / "state"))
    assert is_shipped(calibration_in_force()) and is_shipped(calibration_in_force("input_torque_calibration.csv"))
    assert not is_shipped(history_to_append())  # the state directory's copy
    mine = tmp_path / "torque_calibration.csv"
    mine.write_text("x")
    assert not is_shipped(mine)  # a history of the rig's own (rig.toml, --history) is appended where it is
