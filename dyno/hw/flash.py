"""``dyno flash``: put the firmware on the Nano with avrdude, then ask it over the link what it runs.

The wheel ships a prebuilt HEX pair and its stamp (``firmware.json``: version, protocol, sha256;
``make -C firmware release``), so a Pi needs no AVR toolchain; ``--hex FILE`` flashes a custom build.  The
Nano's bootloader decides the baud: Optiboot (the new one) at 115200, the old ATmegaBOOT at 57600 — tried in
that order, each with its own build (the old bootloader leaves the watchdog running: docs/firmware.md).  A port
another process holds (the service, a `dyno ui`) is refused before avrdude runs: flashing under a running
session would reset its Nano mid-run.
"""

from __future__ import annotations

import glob
import json
import os
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from dyno.errors import ConfigError, DynoError

#: (bootloader, baud) in the order tried; the stamp's "hex" table has a file for each
BOOTLOADERS = (("optiboot", 115200), ("oldboot", 57600))
#: where a Nano shows up, the udev rule's name first (docs/install-pi.md)
PORT_PATTERNS = ("/dev/dyno-nano", "/dev/ttyUSB*", "/dev/ttyACM*")


class FlashError(DynoError):
    """avrdude failed at every baud, or the flashed firmware did not answer as stamped."""


@dataclass(frozen=True)
class Image:
    """What to flash: a HEX file per bootloader and, for the shipped build, its stamp."""

    files: dict  # bootloader name -> Path
    version: str | None = None  # "2.1.0" from the stamp; None for --hex
    protocol: int | None = None


def shipped_image() -> Image:
    """The prebuilt firmware in the package (or the repository's firmware/build), from its stamp."""
    from dyno.resources import resource

    stamp_path = resource("firmware/firmware.json")
    if not stamp_path.is_file():
        raise ConfigError(stamp_path, "file", "no prebuilt firmware in this install (built by `make -C firmware "
                          "release`); flash a build of your own with --hex FILE")
    try:
        stamp = json.loads(stamp_path.read_text())
        files = {name: stamp_path.parent / stamp["hex"][name]["file"] for name, _ in BOOTLOADERS}
        return Image(files, str(stamp["version"]), int(stamp["protocol"]))
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(stamp_path, "stamp", f"version, protocol and hex.optiboot/oldboot.file ({exc})") from None


def custom_image(hex_path: Path) -> Image:
    p = Path(hex_path)
    if not p.is_file():
        raise ConfigError(p, "--hex", "an Intel HEX file (not found)")
    if not p.read_text(errors="replace").startswith(":"):
        raise ConfigError(p, "--hex", "an Intel HEX file (its first line does not start with ':')")
    return Image({name: p for name, _ in BOOTLOADERS})


def find_port(given: str | None, rig_cfg=None) -> str:
    """``--port``, else the rig file's serial port where it exists, else the one Nano plugged in."""
    if given:
        return given
    serial = getattr(rig_cfg, "serial", None)
    if serial is not None and serial.port and Path(serial.port).exists():
        return serial.port
    found = []
    for pattern in PORT_PATTERNS:
        for p in sorted(glob.glob(pattern)):
            if os.path.realpath(p) not in {os.path.realpath(f) for f in found}:
                found.append(p)
    if not found:
        raise ConfigError("--port", "PORT", "no Nano found (" + ", ".join(PORT_PATTERNS) + "): plug in its USB "
                          "cable, or name the port with --port")
    if len(found) > 1:
        raise ConfigError("--port", "PORT", f"several serial ports ({', '.join(found)}): name the Nano's")
    return found[0]


def holders(port: str, proc: Path = Path("/proc")) -> list[tuple[int, str]]:
    """(pid, command) of every process with ``port`` open (other than this one)."""
    target = os.path.realpath(port)
    out = []
    for fd_dir in proc.glob("[0-9]*/fd"):
        pid = int(fd_dir.parent.name)
        if pid == os.getpid():
            continue
        try:
            fds = list(fd_dir.iterdir())
        except OSError:  # gone, or another user's (then not ours to see)
            continue
        for fd in fds:
            try:
                if os.path.realpath(os.readlink(fd)) == target:
                    cmd = (fd_dir.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                    out.append((pid, cmd.strip()))
                    break
            except OSError:
                continue
    return out


def refuse_if_held(port: str) -> None:
    held = holders(port)
    if held:
        pid, cmd = held[0]
        raise ConfigError(port, "port", f"held by process {pid} ({cmd[:60]}): stop it first "
                          "(the service: sudo systemctl stop dyno), then flash")


def avrdude_command(port: str, hex_path: Path, baud: int, avrdude: str = "avrdude") -> list[str]:
    """The command line: the Nano's ATmega328P through its serial bootloader (STK500v1, "arduino")."""
    return [avrdude, "-c", "arduino", "-p", "atmega328p", "-P", port, "-b", str(baud), "-D",
            "-U", f"flash:w:{hex_path}:i"]


def run_avrdude(port: str, image: Image, run=subprocess.run) -> tuple[str, int]:
    """avrdude at each bootloader's baud until one writes; returns (bootloader, baud).  Raises FlashError."""
    exe = shutil.which("avrdude")
    if exe is None:
        raise ConfigError("avrdude", "PATH", "avrdude is not installed (sudo apt-get install avrdude)")
    last = ""
    for name, baud in BOOTLOADERS:
        r = run(avrdude_command(port, image.files[name], baud, exe), capture_output=True, text=True, timeout=180)
        if r.returncode == 0:
            return name, baud
        lines = [x for x in (r.stderr or "").splitlines() if x.strip()]
        last = lines[-1].strip() if lines else f"exit {r.returncode}"
    raise FlashError(f"{port}: avrdude wrote nothing at {' or '.join(str(b) for _, b in BOOTLOADERS)} Bd "
                     f"(last: {last}): check the cable, the port, and that nothing else uses it")


def check_version(transport, image: Image, protocol: str = "v2"):
    """The flashed firmware's INFO over the link: its version, checked against the stamp's when there is one."""
    from dyno.acquisition.reader import make_reader

    info = make_reader(protocol, transport).read_info()
    if info is None:
        raise FlashError("flashed, but the firmware did not answer INFO over the link (a custom build of "
                         "another protocol? `dyno doctor` says more)")
    version = ".".join(str(v) for v in info.fw_version)
    if image.version is not None and version != image.version:
        raise FlashError(f"flashed {image.version}, but the firmware reports {version}")
    return version


def flash(port: str, image: Image, rig_cfg, *, run=subprocess.run, serial_port=None, clock=None) -> dict:
    """Refuse a held port, run avrdude, then read the firmware's INFO over serial (``serial_port``, ``clock``:
    a simulated port for tests).  Returns what the command prints."""
    from dataclasses import replace

    from dyno.transports.serial import open_serial

    refuse_if_held(port)
    bootloader, baud = run_avrdude(port, image, run=run)
    protocol = f"v{image.protocol}" if image.protocol else rig_cfg.protocol
    cfg = replace(rig_cfg, protocol=protocol, serial=replace(rig_cfg.serial, port=port))
    transport = open_serial(cfg, port=serial_port, clock=clock)  # (the open resets the Nano: the new sketch boots)
    try:
        version = check_version(transport, image, protocol)
    finally:
        transport.close()
    return {"port": port, "bootloader": bootloader, "baud": baud, "hex": str(image.files[bootloader]),
            "stamped_version": image.version, "version": version, "protocol": protocol}
