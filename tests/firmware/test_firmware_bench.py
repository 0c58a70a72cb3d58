"""The benchmark's budgets: flash <= 50 %, RAM <= 60 %, every ISR <= 200 cycles (static worst
case and measured), ADC time <= 20 us from the harness's conversions, no v2 false accept."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

pytestmark = [pytest.mark.quick, pytest.mark.firmware]

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_firmware.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_firmware", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def test_firmware_bench_budgets(firmware_build, capsys):
    bench = _bench()
    # Short runs (the bench's defaults: 30 s ADC stress, 10^6 frames per BER).
    assert bench.main(["--seconds", "1", "--adc-seconds", "4", "--fuzz-frames", "3000", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["ok"], rep
    assert rep["size"]["flash_pct"] <= 50 and rep["size"]["ram_pct"] <= 60
    for name in ("INT0", "INT1", "PCINT2", "TWI", "TIMER1_OVF"):
        s = rep["isr"][name]
        assert s["count"] > 0, name
        assert s["max_cycles"] <= 200 and s["static_worst_cycles"] <= 200, (name, s)
        assert s["max_cycles"] <= s["static_worst_cycles"] + 4, (name, s)  # the measurement is within the bound
    assert rep["cli_max_cycles_main"] < 200
    assert rep["events_lost"] == 0
    adc = rep["adc_time"]
    assert adc["lossless"] and adc["conversions"] > 400
    assert adc["max_abs_us"] <= rep["adc_time_bound"]["harness_scale_us"] + 1.0 <= 20.0
    sup = rep["supervisor"]  # issue 37: the run-enable's reaction times within their stated bounds
    assert sup["ok"] and sup["heartbeat"]["cause"] == "heartbeat" and "overspeed" in sup["overspeed"]["cause"], sup
    assert sup["heartbeat"]["reaction_s"] <= 0.202 and sup["overspeed"]["reaction_s"] <= sup["overspeed"]["bound_s"]
    assert [r["ber"] for r in rep["fuzz"]] == [1e-4, 1e-3, 1e-2]
    assert all(r["v2_accepted"] == 0 and r["v2_corrupted"] > 0 for r in rep["fuzz"])


def test_firmware_bench_text_output_names_every_figure(firmware_build, capsys):
    bench = _bench()
    assert bench.main(["--seconds", "0.5", "--adc-seconds", "1", "--fuzz-frames", "500"]) == 0
    out = capsys.readouterr().out
    for key in ("flash", "RAM", "INT0", "INT1", "TWI", "TIMER1_OVF", "ISR worst case", "ADC time",
                "bound from the code", "fuzz", "v2 expected", "v1 accepted", "simulated/wall", "run-enable supervisor",
                "heartbeat: last poll -> off", "over-speed at 4600 rpm", "main-loop pass", "all targets met"):
        assert key in out, (key, out)


def test_static_isr_analysis_counts_a_known_sequence():
    """The static path analysis on a hand-made listing: a skip, a branch and gcc's counted
    shift loop (ldi 3; add; adc; dec; brne) -> the longest path's cycles."""
    bench = _bench()
    code = {
        0x00: (2, "push", "r24"),            # 2
        0x02: (2, "ldi", "r21, 0x03"),       # 1
        0x04: (2, "add", "r24, r24"),        # loop body 1+1+1 = 3, x3, + 2 x 2 taken + 1
        0x06: (2, "adc", "r25, r25"),
        0x08: (2, "dec", "r21"),
        0x0A: (2, "brne", ".-8"),
        0x0C: (2, "sbis", "0x1b, 2"),        # 1 (no skip) / 2 (skip the 2-byte rjmp)
        0x0E: (2, "rjmp", ".+4"),            # 2 -> 0x14
        0x10: (4, "lds", "r24, 0x0100"),     # 2
        0x14: (2, "pop", "r24"),             # 2
        0x16: (2, "reti", ""),               # 4
    }
    loop = 3 * 3 + 2 * 2 + 1
    # longest: push, ldi, loop, sbis skipping (2), lds (2), pop, reti
    assert bench._longest(code, 0) == 2 + 1 + loop + 2 + 2 + 2 + 4
