"""Faults that cannot be forgotten (issue 49, item 5): the standing-fault file in the one state directory the
service and the operator share, and an unreadable or corrupt file as a standing fault of its own.

The verdicts are the driver's behaviour on the fault (re-arm and GO refused), not only what load() returns.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from dyno.errors import SafetyAbort
from dyno import datapaths
from dyno.hw import rig_faults
from dyno.hw.outputs import GpioActuators

pytestmark = pytest.mark.quick

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def state(tmp_path, monkeypatch):
    monkeypatch.setenv("DYNO_STATE_DIR", str(tmp_path / "state"))
    return tmp_path / "state" / "rig_faults.json"


def _wired(rig):
    import dataclasses

    return dataclasses.replace(rig, pins=dataclasses.replace(rig.pins, brake_released_input=27, estop_input=22))


def _driver_refuses(rig, factory, clock, known) -> str:
    act = GpioActuators(_wired(rig), pin_factory=factory, clock=clock, known_faults=known)
    try:
        assert act.finish_release()
        act.safe_state(latch=True)
        assert act.finish_release()
        with pytest.raises(SafetyAbort, match="re-arm refused"):
            act.clear_latch()
        return act.fault_refusal()
    finally:
        act.close()


def test_no_file_is_no_fault(state):
    assert rig_faults.state_path() == state
    assert rig_faults.load() == []


@pytest.mark.parametrize("content", [b"[{\"channel\": \"end_switch\", \"detail\": \"stuck", b"\xff\xfe\x00garbage",
                                     b"{\"channel\": \"end_switch\"}", b"[1, 2]", b"[{\"detail\": \"no channel\"}]"])
def test_a_corrupt_file_is_a_standing_fault_that_refuses_the_re_arm(state, content, rig, factory, clock):
    state.parent.mkdir(parents=True)
    state.write_bytes(content)
    standing = rig_faults.load()
    assert [f["channel"] for f in standing] == ["end_switch"]
    assert str(state) in standing[0]["detail"] and "doctor --toggle" in standing[0]["detail"]
    why = _driver_refuses(rig, factory, clock, standing)
    assert why and "end-of-travel switch" in why


def test_an_unreadable_file_is_a_standing_fault(state, rig, factory, clock):
    state.mkdir(parents=True)  # a directory where the file belongs: reading it fails whoever runs the test
    standing = rig_faults.load()
    assert [f["channel"] for f in standing] == ["end_switch"] and "cannot be read" in standing[0]["detail"]
    assert _driver_refuses(rig, factory, clock, standing)


def test_a_new_fault_recorded_over_a_corrupt_file_keeps_the_unknown_one_until_the_check_clears_it(state):
    state.parent.mkdir(parents=True)
    state.write_text("not json")
    rig_faults.record([{"channel": "end_switch", "detail": "stuck closed", "t_s": 1.0}])
    kept = json.loads(state.read_text())  # the file is readable again, and still says the faults are unknown
    assert len(kept) == 1 and kept[0]["detail"].startswith("unknown")
    assert rig_faults.clear("end_switch") is True  # `dyno doctor --toggle` passed
    assert rig_faults.load() == [] and not state.exists()


def test_clearing_an_unreadable_file_rewrites_it(state):
    state.mkdir(parents=True)
    assert rig_faults.clear("end_switch") is True
    assert rig_faults.load() == []


def test_the_service_and_the_operator_share_one_state_directory():
    unit = (REPO / "hardware" / "dyno.service").read_text()
    env = re.search(r"^Environment=DYNO_STATE_DIR=(\S+)$", unit, re.M)
    assert env, "hardware/dyno.service must set DYNO_STATE_DIR"
    assert Path(env.group(1)) == datapaths.SERVICE_STATE_DIR
    assert re.search(r"^StateDirectory=dyno$", unit, re.M)  # systemd creates it for User=dyno
    mode = re.search(r"^StateDirectoryMode=(\d+)$", unit, re.M)
    assert mode and int(mode.group(1), 8) & 0o070 == 0o070  # the group (the operator's) reads and writes it
    for doc in ("docs/install-pi.md", "docs/safety.md"):
        text = (REPO / doc).read_text()
        assert str(datapaths.SERVICE_STATE_DIR) in text and "DYNO_STATE_DIR" in text, doc


def test_unset_the_service_directory_is_used_where_it_exists(monkeypatch, tmp_path):
    monkeypatch.delenv("DYNO_STATE_DIR", raising=False)
    monkeypatch.setattr(datapaths, "SERVICE_STATE_DIR", tmp_path / "var-lib-dyno")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("XDG_DATA_HOME", raising=False)
    assert rig_faults.state_path() == tmp_path / "home" / ".local" / "share" / "dyno" / "rig_faults.json"
    (tmp_path / "var-lib-dyno").mkdir()
    assert rig_faults.state_path() == tmp_path / "var-lib-dyno" / "rig_faults.json"
