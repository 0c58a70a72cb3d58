"""Build-level facts of the firmware: the PlatformIO environments, the module dependency
graph (no cycle: proto.c once called back into main.cpp), and the old-bootloader build that
never enables the watchdog (in FIL, against the default build that does)."""

from __future__ import annotations

import configparser
import graphlib
import subprocess
from pathlib import Path

import pytest

from dyno.session.firmware_sim import simulate

pytestmark = [pytest.mark.quick, pytest.mark.firmware]

FW = Path(__file__).resolve().parents[2] / "firmware"


def test_platformio_envs_new_bootloader_by_default():
    ini = configparser.ConfigParser(interpolation=None)
    ini.read(FW / "platformio.ini")
    assert ini["platformio"]["default_envs"].strip() == "nanoatmega328new"
    assert ini["platformio"]["src_dir"].strip() == "src"
    new, old = ini["env:nanoatmega328new"], ini["env:nanoatmega328"]
    assert new["board"].strip() == "nanoatmega328new" and old["board"].strip() == "nanoatmega328"
    assert "DYNO_OLD_BOOTLOADER" not in new.get("build_flags", "")
    assert "-DDYNO_OLD_BOOTLOADER=1" in old["build_flags"] and "${env.build_flags}" in old["build_flags"]
    # The same serial buffer sizes as the Makefile's build (RAM budget).
    assert "-DSERIAL_RX_BUFFER_SIZE=32" in ini["env"]["build_flags"]
    make = (FW / "Makefile").read_text()
    assert "-DSERIAL_RX_BUFFER_SIZE=32" in make and "-DDYNO_OLD_BOOTLOADER=1" in make


def _module_graph(objdir: Path) -> dict:
    defined, used = {}, {}
    for obj in sorted(objdir.glob("*.o")):
        out = subprocess.run(["avr-gcc-nm", str(obj)], capture_output=True, text=True, check=True).stdout
        mod = obj.stem
        defined[mod], used[mod] = set(), set()
        for line in out.splitlines():
            parts = line.split()
            if len(parts) == 2 and parts[0] == "U":
                used[mod].add(parts[1])
            elif len(parts) == 3 and parts[1] in "TDBCRtdbr":
                defined[mod].add(parts[2])
    owner = {sym: mod for mod, syms in defined.items() for sym in syms}
    return {mod: {owner[s] for s in syms if s in owner and owner[s] != mod} for mod, syms in used.items()}


def test_firmware_modules_form_no_cycle(firmware_build):
    """Who uses whose symbols, from the objects themselves: acyclic, and nothing depends on
    main (the sketch's setup/loop sit on top of every module)."""
    graph = _module_graph(FW / "build" / "fw")
    assert {"main", "proto", "capture", "ring", "link_i2c"} <= set(graph)
    assert "proto" in graph["main"]  # the graph is real: main uses proto
    order = list(graphlib.TopologicalSorter(graph).static_order())  # raises CycleError on a cycle
    assert order[-1] == "main"
    assert not [m for m, deps in graph.items() if "main" in deps]


@pytest.mark.parametrize("elf_key,watchdog", [("elf", True), ("oldboot_elf", False)])
def test_watchdog_only_with_the_new_bootloader(firmware_build, sim_args, elf_key, watchdog):
    """The default build (Optiboot) runs with the 500 ms watchdog on; the nanoatmega328 build
    (old ATmegaBOOT, which would turn a watchdog reset into a reset loop) never enables it and
    otherwise works the same. Neither writes the EEPROM."""
    rep = simulate(sim_args("--elf", str(firmware_build[elf_key]), "--seconds", "1.5", "--bounce"))
    assert rep["ok"] and rep["accounting"]["exact"]
    assert rep["harness"]["watchdog_enabled"] is watchdog
    assert rep["harness"]["eeprom_writes"] == 0
