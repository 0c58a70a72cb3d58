"""Shared fixtures for the firmware tests: build once per session (file-locked, since
pytest-xdist workers build concurrently), skip cleanly without the AVR toolchain."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from dyno.transports.simavr import toolchain_missing
from tests.fw_build import make as _make

FW = Path(__file__).resolve().parents[2] / "firmware"
BUILD = FW / "build"


@pytest.fixture(scope="session")
def toolchain():
    why = toolchain_missing()
    if why:
        pytest.skip(f"AVR toolchain/simavr not installed: {why}")


@pytest.fixture(scope="session")
def firmware_build(toolchain):
    """Builds the firmware, its INPUT_PULLUP, hang and old-bootloader variants, the v0 sketch
    and the simavr harness;
    returns their paths."""
    res = _make("firmware", "sim", "pullup", "hang", "oldboot", "oldboot-hang")
    assert res.returncode == 0, res.stdout + res.stderr
    return {"elf": BUILD / "dyno_nano.elf", "v0_elf": BUILD / "v0_sketch.elf",
            "pullup_elf": BUILD / "dyno_nano_pullup.elf", "hang_elf": BUILD / "dyno_nano_hang.elf",
            "oldboot_elf": BUILD / "dyno_nano_oldboot.elf", "oldboot_hang_elf": BUILD / "dyno_nano_oldboot_hang.elf",
            "harness": BUILD / "harness", "make_output": res.stdout}


@pytest.fixture
def sim_args():
    """The spec for dyno.session.firmware_sim.simulate, as the CLI builds it from these arguments."""
    from dyno.cli import firmware_sim_cmd

    def make(*argv: str):
        parser = argparse.ArgumentParser()
        firmware_sim_cmd.add_arguments(parser)
        return firmware_sim_cmd.spec_from_args(parser.parse_args(list(argv)))

    return make


make = _make
