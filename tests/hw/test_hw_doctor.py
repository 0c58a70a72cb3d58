"""`dyno doctor`: bad rig files exit 2 with one line naming the field; the report on the simulated rig."""

from __future__ import annotations

import errno

import pytest

from dyno.cli import main
from dyno.rig.config import DEFAULT_RIG_PATH

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2

GOOD = DEFAULT_RIG_PATH.read_text()


def bad_rig(tmp_path, old, new):
    assert old in GOOD, old
    p = tmp_path / "bad.toml"
    p.write_text(GOOD.replace(old, new, 1))
    return p


CASES = [
    ("unknown pin", "brake_enable = 13", "brake_enable = 99", "pins.brake_enable"),
    ("duplicate pin", "engine_kill = 24", "engine_kill = 23", "pins.engine_kill"),
    ("address out of range", "firmware_address = 0x03", "firmware_address = 0x02", "i2c.firmware_address"),
    ("missing field", "full_stroke_s = 8.0", "", "actuator.full_stroke_s"),
    ("unknown key", "poll_hz = 150", "poll_hz = 150\npoll_rate = 3", "poll_rate"),
]


@pytest.mark.parametrize("case,old,new,field", CASES, ids=[c[0] for c in CASES])
def test_hw_doctor_bad_rig_exits_2_with_one_line(tmp_path, capsys, case, old, new, field):
    p = bad_rig(tmp_path, old, new)
    rc = main(["doctor", "--rig", str(p)])
    out, err = capsys.readouterr()
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"dyno doctor: error: {p}: {field}:")
    assert out == ""


def test_hw_doctor_missing_rig_file(tmp_path, capsys):
    assert main(["doctor", "--rig", str(tmp_path / "none.toml")]) == 2
    assert "file: not found" in capsys.readouterr().err


def test_hw_doctor_sim_toggle_report(capsys, tmp_path):
    # K3 fitted (the shipped rig): the driver's path runs through K3's NO contacts, so the step is taken with
    # the kill chain closed for it alone, the engine stopped; the end switch checked both ways
    rc = main(["doctor", "--sim", "--toggle"])
    out = capsys.readouterr().out
    assert rc == 0, out
    for name in ("firmware", "thermometer", "arduino reset", "brake step", "end switch"):
        assert any(line.split()[:1] == ["ok"] and name in line for line in out.splitlines()), (name, out)
    assert "boot id 1 -> 2" in out and out.rstrip().endswith("rig OK")  # v2: a new boot id per boot
    # without K3 the step runs
    rc = main(["doctor", "--sim", "--toggle", "--rig", str(bad_rig(tmp_path, "brake_hold_relay = true",
                                                                    "brake_hold_relay = false"))])
    out = capsys.readouterr().out
    assert rc == 0 and any(line.split()[:1] == ["ok"] and "brake step" in line for line in out.splitlines()), out


def test_hw_doctor_without_toggle_claims_no_pin(monkeypatch):
    import dyno.hw.outputs as outputs
    from dyno.hw.doctor import diagnose
    from dyno.rig.config import load_rig

    monkeypatch.setattr(outputs, "GpioActuators", None)  # any use would raise

    class Empty:
        def i2c_rdwr(self, *msgs):
            raise OSError(errno.EREMOTEIO, "no ACK")

    report = diagnose(load_rig(), bus=Empty())
    by = {c.name: c for c in report.checks}
    assert by["gpio"].status == "skip"
    assert by["firmware"].status == "FAIL" and by["thermometer"].status == "FAIL"
    assert not report.ok


def test_hw_doctor_reads_the_bme280_the_rig_file_fits(tmp_path):
    """As a real process: the simulated rig serves a BME280 only when the rig file declares one; doctor
    reads it through the host's driver and prints the day's J1349 factor; undeclared, it warns."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=str(DEFAULT_RIG_PATH.parents[1]))
    out = subprocess.run([sys.executable, "-m", "dyno", "doctor", "--sim"], capture_output=True,
                         text=True, timeout=120, env=env).stdout  # the shipped rig file declares one
    line = next(x for x in out.splitlines() if "ambient" in x)
    assert line.split()[0] == "ok" and "BME280 0x76" in line and "J1349 factor" in line, out
    rig = bad_rig(tmp_path, 'sensor = "bme280"', 'sensor = "none"')
    out = subprocess.run([sys.executable, "-m", "dyno", "doctor", "--sim", "--rig", str(rig)], capture_output=True,
                         text=True, timeout=120, env=env).stdout
    line = next(x for x in out.splitlines() if "ambient" in x)
    assert line.split()[0] == "warn" and "uncorrected" in line, out


def test_hw_doctor_checks_the_nanos_run_enable():
    """The firmware's capabilities say whether it has the run-enable (issue 37); without it, a rig whose kill
    chain has the Nano's transistor cannot run the engine: a warning naming the fix."""
    from dyno.hw.doctor_report import Report
    from dyno.hw.doctor_nano import check_run_enable
    from dyno.rig.config import load_rig
    from dyno.sim.device import EmulatedFirmware
    from dyno.transports.base import Transport

    class Emu(Transport):
        def __init__(self, fw):
            super().__init__()
            self.fw = fw

        def _transfer(self, request, read_len):
            self.fw.write(request, 0.1)
            return self.fw.read(read_len, 0.1) if read_len else b""

    cfg = load_rig()
    for fw, status in ((EmulatedFirmware(), "ok"), (EmulatedFirmware(supervisor=False), "warn")):
        report = Report()
        check_run_enable(report, "ok", "warn", "skip", cfg, Emu(fw))
        (check,) = report.checks
        assert check.name == "run-enable" and check.status == status, check
    assert "supervisor_timeout_s = 0" in check.detail
