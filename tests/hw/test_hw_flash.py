"""``dyno flash`` (issue 53): the avrdude command line it builds (a fake avrdude on PATH records it), the old
bootloader's baud tried after the new one's, the version read back over a simulated serial link, and the
refusal while another process holds the port."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.errors import ConfigError
from dyno.hw import flash as fl
from dyno.clock import FakeClock
from dyno.rig.config import load_rig
from dyno.sim.device import FW_VERSION
from dyno.sim.rig import SimRig
from dyno.sim.serial_port import SimSerialPort

REPO = Path(__file__).resolve().parents[2]
STAMPED = ".".join(str(v) for v in FW_VERSION)


def _fake_avrdude(bin_dir: Path, log: Path, *, fail_at_baud: str | None = None) -> Path:
    """An avrdude that records its argv (one JSON line per call) and fails at ``fail_at_baud`` as a Nano with
    the other bootloader does (no sync)."""
    bin_dir.mkdir(exist_ok=True)
    exe = bin_dir / "avrdude"
    exe.write_text(f"""#!{sys.executable}
import json, sys
with open({str(log)!r}, "a") as fh:
    fh.write(json.dumps(sys.argv) + "\\n")
if {fail_at_baud!r} is not None and sys.argv[sys.argv.index("-b") + 1] == {fail_at_baud!r}:
    print("avrdude: stk500_recv(): programmer is not responding", file=sys.stderr)
    sys.exit(1)
""")
    exe.chmod(0o755)
    return exe


def _image(tmp_path, version=STAMPED) -> fl.Image:
    files = {}
    for name, _ in fl.BOOTLOADERS:
        files[name] = tmp_path / f"{name}.hex"
        files[name].write_text(":00000001FF\n")
    return fl.Image(files, version, 2)


def _sim():
    clock = FakeClock(start_s=0.0)
    sim = SimRig(clock.now)
    clock.advance(2.0)
    return sim, clock


def _calls(log: Path) -> list[list[str]]:
    return [json.loads(x) for x in log.read_text().splitlines()] if log.exists() else []


@pytest.mark.quick
def test_flash_runs_avrdude_for_the_nano_and_reads_the_new_firmware_back(tmp_path, monkeypatch):
    log = tmp_path / "argv.jsonl"
    exe = _fake_avrdude(tmp_path / "bin", log)
    monkeypatch.setenv("PATH", f"{exe.parent}{os.pathsep}{os.environ['PATH']}")
    image, port = _image(tmp_path), str(tmp_path / "ttyUSB0")
    sim, clock = _sim()
    boot_before = sim.firmware.boot_id
    out = fl.flash(port, image, load_rig(), serial_port=SimSerialPort(sim, clock), clock=clock)
    assert _calls(log) == [[str(exe), "-c", "arduino", "-p", "atmega328p", "-P", port, "-b", "115200", "-D",
                            "-U", f"flash:w:{image.files['optiboot']}:i"]]
    assert out["bootloader"] == "optiboot" and out["baud"] == 115200
    assert out["version"] == STAMPED and sim.firmware.boot_id != boot_before  # read from the sketch after its reset


@pytest.mark.quick
def test_the_old_bootloader_gets_57600_and_its_own_build(tmp_path, monkeypatch):
    log = tmp_path / "argv.jsonl"
    exe = _fake_avrdude(tmp_path / "bin", log, fail_at_baud="115200")
    monkeypatch.setenv("PATH", f"{exe.parent}{os.pathsep}{os.environ['PATH']}")
    image = _image(tmp_path)
    sim, clock = _sim()
    out = fl.flash(str(tmp_path / "ttyUSB0"), image, load_rig(), serial_port=SimSerialPort(sim, clock), clock=clock)
    calls = _calls(log)
    assert [c[c.index("-b") + 1] for c in calls] == ["115200", "57600"]
    assert calls[1][-1] == f"flash:w:{image.files['oldboot']}:i"
    assert out["bootloader"] == "oldboot" and out["baud"] == 57600


@pytest.mark.quick
def test_a_version_other_than_the_stamp_is_an_error(tmp_path, monkeypatch):
    exe = _fake_avrdude(tmp_path / "bin", tmp_path / "argv.jsonl")
    monkeypatch.setenv("PATH", f"{exe.parent}{os.pathsep}{os.environ['PATH']}")
    sim, clock = _sim()
    with pytest.raises(fl.FlashError, match=f"flashed 9.9.9, but the firmware reports {STAMPED}"):
        fl.flash(str(tmp_path / "tty"), _image(tmp_path, "9.9.9"), load_rig(), serial_port=SimSerialPort(sim, clock),
                 clock=clock)


@pytest.mark.quick
def test_the_port_is_found_or_named(tmp_path, monkeypatch):
    monkeypatch.setattr(fl, "PORT_PATTERNS", (str(tmp_path / "ttyUSB*"),))
    rig = load_rig()  # its [serial] port (/dev/ttyUSB0) is not on this machine
    with pytest.raises(ConfigError, match="no Nano found"):
        fl.find_port(None, rig)
    (tmp_path / "ttyUSB0").touch()
    assert fl.find_port(None, rig) == str(tmp_path / "ttyUSB0")
    (tmp_path / "ttyUSB1").touch()
    with pytest.raises(ConfigError, match="several serial ports"):
        fl.find_port(None, rig)
    assert fl.find_port("/dev/ttyS9", rig) == "/dev/ttyS9"


@pytest.mark.quick
def test_a_port_another_process_holds_is_refused_before_avrdude_runs(tmp_path):
    """The service (or any process) has the Nano's port open: one line naming it and how to stop it, exit 2."""
    master, slave = os.openpty()
    port = os.ttyname(slave)
    log = tmp_path / "argv.jsonl"
    exe = _fake_avrdude(tmp_path / "bin", log)
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"], stdin=slave)
    os.close(slave)  # (now only the holder has it open)
    try:
        env = dict(os.environ, PATH=f"{exe.parent}{os.pathsep}{os.environ['PATH']}")
        r = subprocess.run([sys.executable, "-m", "dyno", "flash", "--hex", str(_image(tmp_path).files["optiboot"]),
                            "--port", port], env=env, capture_output=True, text=True, timeout=120)
    finally:
        holder.kill()
        holder.wait()
        os.close(master)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"held by process {holder.pid}" in r.stderr and "sudo systemctl stop dyno" in r.stderr
    assert _calls(log) == []  # avrdude never ran
