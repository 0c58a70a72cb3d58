#!/usr/bin/env python3
"""Firmware figures: flash/RAM use, ISR cycle costs and interrupts-off windows measured
in simavr, and simavr's simulated-to-wall time ratio.

    python bench/bench_firmware.py [--seconds 3] [--json]

Builds the firmware and the harness (``make -C firmware firmware sim``), then:

* flash/RAM from ``avr-size`` (targets: < 50 % flash, < 60 % RAM; RAM is static use,
  .data + .bss + .noinit, the stack comes on top);
* one profiled run (the harness steps instruction by instruction and records, per
  interrupt vector, the cycles from the vector fetch to the end of RETI -- counted
  from the instruction the interrupt arrived after, so an upper bound by up to four
  cycles -- plus the longest cli...sei window in the main program) while the host
  polls at 150 Hz with ACK_POLL at 3800/7600 rpm and a 125 Hz ADC;
* one unprofiled run for the simulated-to-wall ratio.
Target: every ISR < 200 cycles (12.5 us at 16 MHz).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from dyno.acquisition.reader import make_reader  # noqa: E402
from dyno.transports.simavr import SimavrTransport  # noqa: E402

FW = REPO / "firmware"
ELF = FW / "build" / "dyno_nano.elf"
FLASH_BYTES, RAM_BYTES = 30720, 2048
ISR_TARGET_CYCLES = 200


def build() -> None:
    subprocess.run(["make", "-s", "-C", str(FW), "firmware", "sim"], check=True,
                   stdout=subprocess.DEVNULL)


def sizes(elf: Path = ELF) -> dict:
    out = subprocess.run(["avr-size", "-A", str(elf)], check=True, capture_output=True,
                         text=True).stdout
    sec = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            sec[parts[0]] = int(parts[1])
    flash = sec.get(".text", 0) + sec.get(".data", 0)
    ram = sec.get(".data", 0) + sec.get(".bss", 0) + sec.get(".noinit", 0)
    return {"flash_bytes": flash, "flash_pct": round(100 * flash / FLASH_BYTES, 1),
            "ram_bytes": ram, "ram_pct": round(100 * ram / RAM_BYTES, 1)}


def polled_run(seconds: float, profile: bool) -> dict:
    tr = SimavrTransport(ELF, profile=profile, bounce=True)
    wall0 = time.perf_counter()
    try:
        reader = make_reader("v2", tr)
        k, n_events = 0, 0
        while k / 150.0 <= seconds:
            t = k / 150.0
            tr.advance_to(t)
            n_events += len(reader.poll(t))
            k += 1
        stats = tr.harness_stats()
    finally:
        tr.close()
    stats["host_wall_s"] = time.perf_counter() - wall0
    stats["events"] = n_events
    stats["events_lost"] = reader.events_lost
    return stats


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    build()
    size = sizes()
    prof = polled_run(args.seconds, profile=True)
    plain = polled_run(args.seconds, profile=False)
    isr = {name: {"count": s["count"], "mean_cycles": s["mean_cycles"], "max_cycles": s["max_cycles"],
                  "max_us": round(s["max_cycles"] / 16.0, 2)}
           for name, s in prof["isr"].items()}
    longest_isr = max((s["max_cycles"] for s in prof["isr"].values()), default=0)
    report = {
        "size": size,
        "targets": {"flash_pct_lt": 50, "ram_pct_lt": 60, "isr_cycles_lt": ISR_TARGET_CYCLES},
        "isr": isr,
        "cli_max_cycles_main": prof["cli_max_cycles"],
        "interrupts_off_max_cycles": max(longest_isr, prof["cli_max_cycles"]),
        "i2c_stretch_max_us": prof["i2c"]["stretch_max_us"],
        "sim_per_wall": plain["sim_per_wall"],
        "sim_per_wall_profiled": prof["sim_per_wall"],
        "host_sim_per_wall": round(plain["sim_s"] / plain["host_wall_s"], 3),
        "events_lost": plain["events_lost"],
        "ok": bool(size["flash_pct"] < 50 and size["ram_pct"] < 60
                   and all(s["max_cycles"] < ISR_TARGET_CYCLES for s in prof["isr"].values())),
    }
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"flash  {size['flash_bytes']:6d} B  {size['flash_pct']:5.1f} %   (target < 50 %)")
    print(f"RAM    {size['ram_bytes']:6d} B  {size['ram_pct']:5.1f} %   (target < 60 %, static)")
    print(f"ISR cycles over {args.seconds:g} simulated s (vector fetch .. RETI; target < {ISR_TARGET_CYCLES}):")
    for name, s in isr.items():
        flag = "" if s["max_cycles"] < ISR_TARGET_CYCLES else "   <-- over target"
        print(f"  {name:12s} n={s['count']:6d}  mean {s['mean_cycles']:6.1f}  max {s['max_cycles']:4d}"
              f"  ({s['max_us']:.2f} us){flag}")
    print(f"longest cli window in main code: {report['cli_max_cycles_main']} cycles")
    print(f"longest interrupts-off window:   {report['interrupts_off_max_cycles']} cycles "
          f"({report['interrupts_off_max_cycles'] / 16:.2f} us)")
    print(f"longest I2C clock stretch:       {report['i2c_stretch_max_us']:.2f} us")
    print(f"simavr simulated/wall: {report['sim_per_wall']:.2f}x (harness), "
          f"{report['host_sim_per_wall']:.2f}x with the Python host; profiled {report['sim_per_wall_profiled']:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
