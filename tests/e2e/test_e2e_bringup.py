"""Bring-up on a real Pi (issue 40), tried on the simulated rig: a link that fits its bus, a doctor that finds
wiring faults, the serial port's auto-reset."""

from __future__ import annotations

import errno
import json
from pathlib import Path

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.cli import main
from dyno.control.plans import plan_named

REPO = Path(__file__).resolve().parents[2]


def _rig(tmp_path, name="rig.toml", **subs) -> Path:
    text = (REPO / "hardware" / "rig.toml").read_text()
    for old, new in subs.items():
        assert old in text, old
        text = text.replace(old, new)
    p = tmp_path / name
    p.write_text(text)
    return p


def test_a_poll_rate_the_bus_cannot_carry_is_refused_in_one_line(tmp_path, capsys):
    """50 kHz SCL (the old default): one poll is 363 clocks, 7.3 ms; at the rig file's over-speed limits the
    events alone need more than 60 % of the bus at any poll rate that drains them: refused, derate or not."""
    rig = _rig(tmp_path, **{"bus_speed_hz = 100000": "bus_speed_hz = 50000"})
    code = main(["run", "--sim", "--headless", "--json", "--mock-pins", "--rig", str(rig),
                 "--out", str(tmp_path / "run")])
    cap = capsys.readouterr()
    assert code == 2 and not (tmp_path / "run").exists()
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "poll_hz: no poll rate" in lines[0], cap.err
    assert json.loads(cap.out)["exit_code"] == 2


def test_a_poll_rate_the_bus_cannot_carry_is_derated_to_fit_and_said(tmp_path, capsys):
    """200 polls a second at 100 kHz, ``derate`` at its default: the run polls at the fastest rate that fits,
    says so, and reports the link's planned and measured busiest second; the measured share, every transaction
    charged at the bus's clock, within the plan (which counts the bursts, retries and boot commands too)."""
    from dyno.rig.config import load_rig
    from dyno.transports.budget import max_poll_hz

    rig = _rig(tmp_path, **{"\npoll_hz = 150 ": "\npoll_hz = 200 "})
    fits_hz = max_poll_hz(load_rig(rig))
    code = main(["run", "--sim", "--headless", "--json", "--rig", str(rig), "--plan", "thesis-step",
                 "--out", str(tmp_path / "run")])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert f"poll_hz: derated from 200 Hz to {fits_hz} Hz" in cap.err and 150 <= fits_hz < 200
    link = json.loads(cap.out)["link"]
    assert link["poll_hz"] == fits_hz and link["derated_from_hz"] == 200 and link["clock_hz"] == 100_000
    assert link["planned_busy_frac"] <= 0.6 and 0.3 < link["measured_busy_frac"] <= link["planned_busy_frac"]
    assert set(link["planned_by_kind"]) >= {"poll", "retry", "boot", "supervisor", "thermometer"}
    assert ("link_busy" in link["warnings"]) == (link["measured_busy_frac"] > 0.6), link


def test_the_default_rigs_link_fits_with_its_margin_and_loses_nothing(tmp_path):
    r = run_test(RunSpec(sim=True, seed=3, out_dir=tmp_path / "run"))
    link = r["link"]
    assert link["transport"] == "i2c" and link["clock_hz"] == 100_000 and link["poll_hz"] == 150
    assert link["busy_basis"] == "measured"
    # the worst second as the transactions used it: the polls, the bursts and the thermometer's reads
    assert 0.5 <= link["bus_busy_frac"] <= 0.6, link
    assert link["frames_lost"] == 0 and link["events_lost"] == 0


def test_a_serial_rig_is_charged_at_its_baud(tmp_path):
    rig = _rig(tmp_path, **{'transport = "i2c"': 'transport = "serial"'})
    r = run_test(RunSpec(sim=True, seed=3, out_dir=tmp_path / "run", rig_path=rig,
                            plan=plan_named("thesis-step")))
    link = r["link"]
    assert link["transport"] == "serial" and link["clock_hz"] == 115_200
    # 150 exchanges of (6 + 2) + (<= 32 + 2) bytes at 10 bits each: at most 55 %; frames are unpadded on serial
    assert 0.3 < link["bus_busy_frac"] <= 0.6, link


@pytest.mark.parametrize("drill,channel", [(None, None), ("hall-dead:primary", "hall primary"),
                                           ("adc-stuck", "adc (output torque)"), ("endswitch-stuck-closed", "end switch")])
def test_doctor_finds_each_wiring_fault_on_the_twin(tmp_path, capsys, drill, channel):
    """`dyno doctor --sim --mock-pins --rig R --drill NAME`: the fault there from the start; a non-zero exit and a
    line naming the channel (and its wire); without a drill, exit 0."""
    # the shipped rig as it is: K3 fitted, the end switch declared (doctor steps the brake with the chain closed)
    rig = _rig(tmp_path)
    code = main(["doctor", "--sim", "--mock-pins", "--rig", str(rig)] + (["--drill", drill] if drill else []))
    out = capsys.readouterr().out
    if drill is None:
        assert code == 0 and "rig OK" in out and "FAIL" not in out, out
        for name in ("hall primary", "hall secondary", "adc (output torque)", "link", "end switch", "link budget"):
            assert any(ln.strip().startswith("ok") and name in ln for ln in out.splitlines()), (name, out)
    else:
        fails = [ln for ln in out.splitlines() if ln.strip().startswith("FAIL")]
        assert code == 1 and any(channel in ln for ln in fails), out
        assert "rig NOT ready" in out


def test_doctor_names_a_dead_secondary_after_the_operator_turned_it(capsys):
    code = main(["doctor", "--sim", "--drill", "hall-dead:secondary"])
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if "hall secondary" in ln)
    assert code == 1 and "FAIL" in line and "Nano D3" in line


def test_doctor_over_serial_survives_the_auto_reset(capsys):
    """`dyno doctor --sim --transport serial`: opening the port resets the simulated Nano, which answers
    nothing for its bootloader's second; the doctor waits for the new boot and passes."""
    code = main(["doctor", "--sim", "--transport", "serial"])
    out = capsys.readouterr().out
    assert code == 0 and "rig OK" in out, out
    assert "reset cause: external" in out  # the boot it found is the one its own open caused


def test_an_eio_on_the_broadcom_controller_is_a_stretch_timeout_not_a_nack():
    import dataclasses

    from dyno.rig.config import load_rig
    from dyno.transports.i2c import open_i2c

    class Bus:
        def i2c_rdwr(self, *msgs):
            raise OSError(errno.EIO, "Input/output error")

    hw_rig = load_rig()
    on_bus1 = dataclasses.replace(hw_rig, i2c=dataclasses.replace(hw_rig.i2c, bus=1, retries=0))
    on_gpio = dataclasses.replace(hw_rig, i2c=dataclasses.replace(hw_rig.i2c, bus=3, retries=0))
    for cfg, cause in ((on_bus1, "stretch_timeout"), (on_gpio, "nack")):
        t = open_i2c(cfg, bus=Bus())
        with pytest.raises(Exception):
            t.transfer(b"\x10", 32)
        assert dict(t.failures) == {cause: 1}


def test_the_bus_is_not_reset_again_while_the_nano_boots():
    """After pulsing RESET the Nano's bootloader NACKs for ~1 s: those failures must not pulse it again (with
    20 failures a reset at 150 Hz, the old transport reset it every ~0.13 s, for ever)."""
    from dyno.clock import FakeClock
    from dyno.transports.i2c import RecoveringI2CTransport

    class Bus:
        def i2c_rdwr(self, *msgs):
            raise OSError(errno.EREMOTEIO, "NACK")

    clock = FakeClock()
    resets = []
    t = RecoveringI2CTransport(Bus(), 0x03, retries=0, reset_after_failures=20, reset=lambda: resets.append(1),
                               clock=clock)
    for _ in range(150):  # one second of polls at 150 Hz, every one NACKed
        with pytest.raises(Exception):
            t.transfer(b"\x10", 32)
        clock.advance(1 / 150)
    assert len(resets) == 1


def test_doctor_on_the_twin_as_a_real_process(tmp_path):
    """`dyno doctor --sim --mock-pins --drill hall-dead:primary` as a user types it: exit 1, the channel named,
    no traceback; without the drill, exit 0."""
    import os
    import subprocess
    import sys

    rig = _rig(tmp_path)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    base = [sys.executable, "-m", "dyno", "doctor", "--sim", "--mock-pins", "--rig", str(rig)]
    bad = subprocess.run(base + ["--drill", "hall-dead:primary"], capture_output=True, text=True, timeout=120,
                         env=env, cwd=tmp_path)
    assert bad.returncode == 1 and "Traceback" not in bad.stderr, bad.stderr
    assert any(ln.strip().startswith("FAIL") and "hall primary" in ln for ln in bad.stdout.splitlines()), bad.stdout
    good = subprocess.run(base, capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
    assert good.returncode == 0 and good.stdout.rstrip().endswith("rig OK"), good.stdout + good.stderr
