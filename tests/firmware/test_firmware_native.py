"""Native unit tests of the firmware's pure-C modules, and the offline AVR build."""

from __future__ import annotations

import re

import pytest

from .conftest import make

pytestmark = [pytest.mark.quick, pytest.mark.firmware]


def test_firmware_native_unit_tests(toolchain):
    # ring wrap/overflow, CRC-16/CRC-32C, framing against dyno/protocol/vectors/v2.hex, timestamp
    # extension across timer overflow and 2^32, command checks, COBS, ack/re-send.
    res = make("test")
    out = res.stdout + res.stderr
    assert res.returncode == 0, out
    assert re.search(r"\b0 failures\b", out), out
    assert re.search(r"vectors: 4 crc32c, 1\d frames, 1 info, [6-9] cmd, [4-9] badcmd", out), out
    assert "proto lossless" in out
    # issue 37: tag 5, FLAG_RUN, the capabilities' bit 0x02, SET_SUPERVISOR against v2-supervisor.hex
    assert re.search(r"supervisor vectors: [5-9] frames, [3-9] caps, 1 info, [2-9] cmd, [2-9] badcmd", out), out


def test_firmware_build_fits_budget(firmware_build):
    out = firmware_build["make_output"]
    # make prints e.g. "flash: 6192 / 30720 bytes (20.2%)" and "ram: 942 / 2048 bytes (46.0%)"
    flash = re.search(r"flash:\s+(\d+) / 30720 bytes \(([\d.]+)%\)", out)
    ram = re.search(r"ram:\s+(\d+) / 2048 bytes \(([\d.]+)%\)", out)
    assert flash and ram, out
    assert float(flash.group(2)) < 50.0
    assert float(ram.group(2)) < 60.0
    assert firmware_build["elf"].is_file()
    assert firmware_build["elf"].with_suffix(".hex").is_file()
