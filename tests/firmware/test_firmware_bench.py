"""The benchmark's budgets: flash < 50 %, RAM < 60 %, every ISR < 200 cycles."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

pytestmark = pytest.mark.firmware

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_firmware.py"


def test_firmware_bench_budgets(firmware_build, capsys):
    spec = importlib.util.spec_from_file_location("bench_firmware", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--seconds", "1"]) == 0
    out = capsys.readouterr().out
    for key in ("flash", "RAM", "INT0", "INT1", "TWI", "TIMER1_OVF", "interrupts-off", "simulated/wall"):
        assert key in out, out
    size = bench.sizes()
    assert size["flash_pct"] < 50 and size["ram_pct"] < 60
    prof = bench.polled_run(1.0, profile=True)
    for name in ("INT0", "INT1", "TWI", "TIMER1_OVF"):
        assert prof["isr"][name]["count"] > 0, name
    over = {n: s["max_cycles"] for n, s in prof["isr"].items() if s["max_cycles"] >= 200}
    assert not over, over
    assert prof["cli_max_cycles"] < 200
    assert prof["events_lost"] == 0
