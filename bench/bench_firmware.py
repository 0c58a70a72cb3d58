#!/usr/bin/env python3
"""Firmware figures: flash/RAM use, ISR worst cases (static and measured in simavr), the
ADC timestamp's worst case against the harness's conversion times, the link's false
accepts under bit errors (v2 against v1), and simavr's simulated-to-wall ratio.

    python bench/bench_firmware.py [--seconds 3] [--adc-seconds 30] [--fuzz-frames 1000000] [--json] [--quick]

``--quick`` (CI's smoke run): 0.5 simulated s per polled run, a 2 s ADC stress run, 10,000 fuzz frames per
bit-error rate.  Without the AVR toolchain or simavr it prints one line saying what is missing and exits
(0 with ``--quick``, 1 without), as the firmware tests skip (``dyno.transports.simavr.toolchain_missing``).

Builds the firmware and the harness (``make -C firmware firmware sim``), then:

* flash/RAM from ``avr-size`` (targets: <= 50 % flash, <= 60 % RAM; RAM is static use,
  .data + .bss + .noinit, the stack comes on top);
* ISR worst case, two ways: *static*, the longest path through each vector's machine
  code (AVR cycle counts, from the interrupt response to RETI; a vector with a loop is
  left to the measurement), and *measured*, one profiled run (the harness steps
  instruction by instruction and records, per vector, the cycles from the vector fetch
  to the end of RETI, counted from the instruction the interrupt arrived after -- an
  upper bound by up to four cycles -- plus the longest cli...sei window in the main
  program) while the host polls at 150 Hz at 3800/7600 rpm with a 125 Hz ADC;
* ADC timestamp worst case: a stress run (both Hall channels near 15,000 rpm, ringing,
  200 Hz of spikes, jittered polls) compared with the harness's conversion times, and
  the bound from the code (the longest ISR that cannot take RDY's time, plus the entry
  of the ISR that does);
* fuzz: N realistic frames per bit-error rate through a bit-error channel to a session
  expecting each (``bench/bench_host.py``'s channel), false accepts for v2 (CRC-32C) and
  v1 (CRC-16) with v2's computed expectation beside them (docs/protocol.md);
* one unprofiled run for the simulated-to-wall ratio;
* the run-enable supervisor's reaction times (issue 37), from D7 as the harness times it: heartbeat
  (the host stops polling: its last poll -> pin off), over-speed (4,600 rpm against the shipped 4,200:
  the falling edge that ends the first short period -> pin off, and the output's arming -> pin off), and
  one main-loop pass, the longest (the old-bootloader build toggles D7 on every pass while on).
Targets: every ISR <= 200 cycles (12.5 us at 16 MHz), ADC time <= 20 us; the supervisor: heartbeat
<= timeout + 2 ms (a loop pass < 1 ms, plus the last poll's own transfer, ~0.3 ms), over-speed <= the
pulse's width + 1 ms after the edge that ends the first short period (the ISR takes a pulse at its end,
the loop then needs a pass) and <= 2 periods at the limit + 1 ms after the speed is above the limit,
a loop pass < 1 ms. Exits 1 when a target is missed.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import re
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from dyno.acquisition.reader import make_reader  # noqa: E402
from dyno.transports.simavr import SimavrTransport, toolchain_missing  # noqa: E402

FW = REPO / "firmware"
ELF = FW / "build" / "dyno_nano.elf"
FLASH_BYTES, RAM_BYTES = 30720, 2048
ISR_TARGET_CYCLES = 200
ADC_TARGET_US = 20.0
VECTOR_NAMES = {1: "INT0", 2: "INT1", 3: "PCINT0", 5: "PCINT2", 13: "TIMER1_OVF", 16: "TIMER0_OVF", 18: "USART_RX",
                19: "USART_UDRE", 24: "TWI"}


def build() -> None:
    (FW / "build").mkdir(exist_ok=True)
    with open(FW / "build" / ".make.lock", "w") as lock:  # the lock tests/firmware builds under
        fcntl.flock(lock, fcntl.LOCK_EX)
        subprocess.run(["make", "-s", "-C", str(FW), "firmware", "sim"], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


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


# -- static worst case: longest path through a vector's code ---------------------------
# ATmega328P cycle counts (datasheet instruction set summary); everything else is 1.
_CYCLES = {"push": 2, "pop": 2, "lds": 2, "sts": 2, "st": 2, "std": 2, "ld": 2, "ldd": 2, "mul": 2,
           "adiw": 2, "sbiw": 2, "sbi": 2, "cbi": 2, "rjmp": 2, "jmp": 3, "reti": 4, "ret": 4,
           "call": 4, "rcall": 3, "lpm": 3, "ijmp": 2, "icall": 3}
_SKIPS = ("sbis", "sbic", "sbrs", "sbrc", "cpse")
RESPONSE_CYCLES = 4 + 3  # interrupt response, then the vector table's jmp


def _code(elf: Path) -> dict:
    """address -> (size in bytes, mnemonic, operands) over the whole .text."""
    out = subprocess.run(["avr-objdump", "-d", str(elf)], capture_output=True, text=True, check=True).stdout
    code = {}
    for line in out.splitlines():
        m = re.match(r"^\s+([0-9a-f]+):\s+((?:[0-9a-f]{2} )+)\s*(\S+)\s*([^;]*)", line)
        if m:
            code[int(m.group(1), 16)] = (len(m.group(2).split()), m.group(3), m.group(4).strip())
    return code


def _vector_targets(code: dict) -> dict:
    """vector number -> its handler's address (from the jmp in the vector table)."""
    out = {}
    for v in range(1, 26):
        ins = code.get(4 * v)
        if ins and ins[1] == "jmp":
            out[v] = int(ins[2].split()[0], 16)
    return out


class _Loop(Exception):
    pass


def _counted_loop(code: dict, a: int):
    """`ldi rN, K` followed by a straight-line body ending `dec rN; brne <body>` (gcc's
    shift loops): (cycles of the K passes, address after the loop), else None."""
    size, _, args = code[a]
    m = re.match(r"(r\d+), 0x([0-9a-fA-F]+)", args)
    if not m:
        return None
    reg, k = m.group(1), int(m.group(2), 16) or 256
    head = b = a + size
    body = 0
    while b in code:
        bs, bop, bargs = code[b]
        if bop == "brne" and b + 2 + int(re.search(r"\.([+-]\d+)", bargs).group(1)) == head:
            prev = code.get(b - 2)
            if not prev or prev[1] != "dec" or prev[2] != reg:
                return None
            return k * body + (k - 1) * 2 + 1, b + bs
        if bop.startswith("br") or bop in _SKIPS or bop.endswith("jmp") or bop in ("call", "rcall", "ret", "reti"):
            return None
        body += _CYCLES.get(bop, 1)
        b += bs
    return None


def _longest(code: dict, start: int) -> int:
    """Cycles of the longest path from `start` to its ret/reti (raises _Loop on a cycle)."""
    memo: dict = {}
    onpath: set = set()

    def walk(a: int) -> int:
        if a in memo:
            return memo[a]
        if a in onpath:
            raise _Loop(hex(a))
        onpath.add(a)
        size, op, args = code[a]
        nxt = a + size
        loop = _counted_loop(code, a) if op == "ldi" else None
        if op in ("ret", "reti"):
            c = _CYCLES[op]
        elif loop:
            c = 1 + loop[0] + walk(loop[1])
        elif op in _SKIPS:
            skipped = code[nxt][0]
            c = max(1 + walk(nxt), (2 if skipped == 2 else 3) + walk(nxt + skipped))
        elif op == "rjmp":
            c = 2 + walk(a + 2 + int(re.search(r"\.([+-]\d+)", args).group(1)))
        elif op == "jmp":
            c = 3 + walk(int(args.split()[0], 16))
        elif op.startswith("br"):
            c = max(1 + walk(nxt), 2 + walk(a + 2 + int(re.search(r"\.([+-]\d+)", args).group(1))))
        elif op in ("call", "rcall"):
            tgt = int(args.split()[0], 16) if op == "call" else a + 2 + int(re.search(r"\.([+-]\d+)", args).group(1))
            c = _CYCLES[op] + _longest(code, tgt) + walk(nxt)
        elif op in ("ijmp", "icall"):
            raise _Loop(f"indirect {op} at {a:x}")
        else:
            c = _CYCLES.get(op, 1) + walk(nxt)
        onpath.discard(a)
        memo[a] = c
        return c

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 20000))
    return walk(start)


def _cycles_to_timer_read(code: dict, start: int) -> int:
    """Cycles from a handler's first instruction to its first read of TCNT1 (0x84)."""
    a, c = start, 0
    while a in code:
        size, op, args = code[a]
        if op == "lds" and args.endswith("0x0084"):
            return c + 2
        if op in ("ret", "reti") or op.startswith("br") or op in _SKIPS or op.endswith("jmp"):
            break
        c += _CYCLES.get(op, 1)
        a += size
    return -1


def static_isr(elf: Path = ELF) -> dict:
    """Per vector: worst-case cycles from the interrupt to the end of RETI (None: has a loop),
    and for the ISRs that time RDY, cycles from the interrupt to their Timer1 read."""
    code = _code(elf)
    out = {}
    for v, addr in _vector_targets(code).items():
        if addr == _vector_targets(code).get(0, -1):
            continue
        name = VECTOR_NAMES.get(v, f"vector_{v}")
        try:
            worst = RESPONSE_CYCLES + _longest(code, addr)
        except (_Loop, KeyError):
            worst = None
        t = _cycles_to_timer_read(code, addr)
        out[name] = {"worst_cycles": worst, "to_timer_read_cycles": RESPONSE_CYCLES + t if t >= 0 else None}
    return {k: v for k, v in out.items() if not k.startswith("vector_")}


# -- runs in simavr ----------------------------------------------------------------------
def polled_run(seconds: float, profile: bool) -> dict:
    # the two-converter rig (issue 27): the input torque AD7171 fitted and enabled by the host; the run-enable
    # supervisor armed with the shipped limits (issue 37) as the host does at every boot
    from dyno.protocol import v2

    tr = SimavrTransport(ELF, profile=profile, bounce=True, input_hz=125.0)
    wall0 = time.perf_counter()
    try:
        reader = make_reader("v2", tr)
        reader.want_input = True
        k, n_events, armed = 0, 0, False
        while k / 150.0 <= seconds:
            t = k / 150.0
            tr.advance_to(t)
            n_events += len(reader.poll(t))
            if not armed and reader.boot_id is not None:
                reader.command(v2.supervisor_command(4200.0, 7800.0, 0.2))
                armed = True
            k += 1
        stats = tr.harness_stats()
    finally:
        tr.close()
    stats["host_wall_s"] = time.perf_counter() - wall0
    stats["events"] = n_events
    stats["events_lost"] = reader.events_lost
    return stats


def adc_stress(seconds: float) -> dict:
    """ADC time error against the harness's conversions with the ISRs as busy as the rig gets."""
    from dyno.session.firmware_sim import FirmwareSimSpec, simulate

    rep = simulate(FirmwareSimSpec(elf=str(ELF), seconds=seconds, primary_rpm=15000.0, secondary_rpm=14000.0,
                                   bounce=True, glitch_hz=200.0, poll_jitter=0.5, seed=5, input_hz=125.0))
    err = rep["adc_time_error_us"] or {}
    inp = rep.get("input") or {}
    ierr = inp.get("time_error_us") or {}
    return {"conversions": rep["events"]["adc"]["received"], "max_abs_us": err.get("max_abs_us"),
            "mean_us": err.get("mean_us"), "lossless": rep["ok"],
            # the second converter (issue 27): its conversions and RDY time error, lossless by its codes
            "input_conversions": inp.get("received"), "input_max_abs_us": ierr.get("max_abs_us"),
            "input_mean_us": ierr.get("mean_us"), "input_lossless": inp.get("distinct_codes_consecutive")}


SUP_TIMEOUT_S, SUP_LIMIT_RPM, SUP_TEST_RPM, LOOP_PASS_US = 0.2, 4200.0, 4600.0, 1000.0


def supervisor_reactions(seconds: float) -> dict:
    """The run-enable's reaction times in simavr (``dyno firmware-sim`` with hardware/rig.toml's limits)."""
    from dyno.session.firmware_sim import FirmwareSimSpec, simulate

    def sim(**kw):
        return simulate(FirmwareSimSpec(elf=str(ELF), **kw))

    stop = max(0.3, seconds / 2)
    hb = sim(seconds=stop + 0.4, host_stop_at=stop)["supervisor"]
    hb_s = hb["off_at_s"] - hb["last_poll_s"] if hb["off_at_s"] is not None else None
    rep = sim(seconds=0.3, primary_rpm=SUP_TEST_RPM)
    ov = rep["supervisor"]
    period_s = 60.0 / SUP_TEST_RPM
    first_us = rep["harness"]["first_edge_us"][0]
    width_s = rep["harness"]["pulse_us"][0] / 1e6
    edge_s, ov_s, onset_s = None, None, None
    if ov["off_at_s"] is not None:
        k = 1
        while first_us / 1e6 + k * period_s <= ov["on_at_s"]:
            k += 1
        edge_s = first_us / 1e6 + k * period_s
        ov_s = ov["off_at_s"] - edge_s
        onset_s = ov["off_at_s"] - max(ov["on_at_s"], first_us / 1e6)
    pump = simulate(FirmwareSimSpec(elf=str(ELF.with_name("dyno_nano_oldboot.elf")), seconds=min(seconds, 1.0),
                                    bounce=True, input_hz=125.0))["supervisor"]
    out = {"timeout_s": SUP_TIMEOUT_S,
           "heartbeat": {"last_poll_s": hb["last_poll_s"], "off_at_s": hb["off_at_s"], "cause": hb["cause"],
                         "reaction_s": hb_s, "bound_s": SUP_TIMEOUT_S + 2 * LOOP_PASS_US / 1e6},
           "overspeed": {"rpm": SUP_TEST_RPM, "limit_rpm": SUP_LIMIT_RPM, "cause": ov["cause"],
                         "first_short_period_end_s": edge_s, "off_at_s": ov["off_at_s"],
                         "reaction_s": ov_s, "bound_s": width_s + LOOP_PASS_US / 1e6, "pulse_width_s": width_s,
                         "from_onset_s": onset_s, "onset_bound_s": 2 * 60.0 / SUP_LIMIT_RPM + LOOP_PASS_US / 1e6},
           "loop_pass_max_us": pump["max_pulse_interval_us"], "loop_pass_bound_us": LOOP_PASS_US,
           "pump_pulsing": pump["pulsing"]}
    out["ok"] = bool(hb_s is not None and "heartbeat" in (hb["cause"] or "") and SUP_TIMEOUT_S < hb_s <= out["heartbeat"]["bound_s"]
                     and ov_s is not None and "overspeed" in (ov["cause"] or "") and 0 < ov_s <= out["overspeed"]["bound_s"]
                     and onset_s <= out["overspeed"]["onset_bound_s"]
                     and pump["pulsing"] and 0 < (pump["max_pulse_interval_us"] or 0) < LOOP_PASS_US)
    return out


def fuzz(n_frames: int, bers=(1e-4, 1e-3, 1e-2)) -> list[dict]:
    import bench_host

    rows = []
    frames = {ver: bench_host.realistic_frames(n_frames, seed=1, version=ver) for ver in (1, 2)}
    for i, ber in enumerate(bers):
        row = {"ber": ber, "frames": n_frames}
        for ver in (2, 1):
            r = bench_host.false_accepts(frames[ver], ber, seed=100 + i, version=ver)
            row[f"v{ver}_corrupted"] = r["corrupted"]
            row[f"v{ver}_accepted"] = r["false_accepts"]
        row["v2_expected"] = bench_host.expected_false_accepts_v2(frames[2], ber)
        rows.append(row)
    return rows


def adc_bound(static: dict, measured_isr: dict, cli_max_cycles: int) -> dict:
    """RDY's time is taken by the first ISR to run after it (a Hall ISR or the pin change
    ISR, at its Timer1 read). The worst case: RDY falls just as something that cannot take
    it starts -- another ISR (TWI, serial, timers), a Hall ISR past its Timer1 read, or a
    cli window of the main loop -- then one main-program instruction (<= 4 cycles) and
    the taking ISR's entry up to its Timer1 read."""
    takers = ("INT0", "INT1", "PCINT2", "PCINT0")
    entry = max((static[n]["to_timer_read_cycles"] or 0) for n in takers if n in static)
    blockers = [cli_max_cycles]
    for name, s in static.items():
        c = s["worst_cycles"] if s["worst_cycles"] is not None else measured_isr.get(name, {}).get("max_cycles")
        if c is None:
            continue
        if name in takers:  # busy past its own Timer1 read
            c -= s["to_timer_read_cycles"] or 0
        blockers.append(c)
    worst = max(blockers) + 4 + entry
    # firmware-sim's error puts the device clock on the harness's by the Hall edges, whose
    # own timestamps come `entry` cycles after the edge: on that scale the bound is less.
    hall_entry = static.get("INT0", {}).get("to_timer_read_cycles") or 0
    return {"cycles": worst, "us": round(worst / 16.0, 2), "harness_scale_us": round((worst - hall_entry) / 16.0, 2)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="profiled run (simulated s)")
    ap.add_argument("--adc-seconds", type=float, default=30.0, help="ADC stress run (simulated s)")
    ap.add_argument("--fuzz-frames", type=int, default=1_000_000, help="frames per bit-error rate (0: skip)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--quick", action="store_true",
                    help="CI smoke run: 0.5 s polled runs, 2 s ADC stress, 10,000 fuzz frames per rate; "
                         "exits 0 with one line if the AVR toolchain/simavr is missing")
    args = ap.parse_args(argv)
    why = toolchain_missing()
    if why:
        print(f"bench_firmware: skipped, AVR toolchain/simavr not installed: {why}")
        return 0 if args.quick else 1
    if args.quick:
        args.seconds, args.adc_seconds, args.fuzz_frames = 0.5, 2.0, min(args.fuzz_frames, 10_000)
    build()
    size = sizes()
    static = static_isr()
    prof = polled_run(args.seconds, profile=True)
    plain = polled_run(args.seconds, profile=False)
    adc = adc_stress(args.adc_seconds)
    isr = {name: {"count": s["count"], "mean_cycles": s["mean_cycles"], "max_cycles": s["max_cycles"],
                  "max_us": round(s["max_cycles"] / 16.0, 2),
                  "static_worst_cycles": static.get(name, {}).get("worst_cycles")}
           for name, s in prof["isr"].items()}
    bound = adc_bound(static, prof["isr"], prof["cli_max_cycles"])
    fz = fuzz(args.fuzz_frames) if args.fuzz_frames > 0 else []
    sup = supervisor_reactions(args.seconds)
    worst_isr = max(max(s["max_cycles"], s["static_worst_cycles"] or 0) for s in isr.values())
    report = {
        "size": size,
        "targets": {"flash_pct_le": 50, "ram_pct_le": 60, "isr_cycles_le": ISR_TARGET_CYCLES,
                    "adc_time_us_le": ADC_TARGET_US},
        "isr": isr,
        "isr_worst_cycles": worst_isr,
        "cli_max_cycles_main": prof["cli_max_cycles"],
        "interrupts_off_max_cycles": max(worst_isr, prof["cli_max_cycles"]),
        "i2c_stretch_max_us": prof["i2c"]["stretch_max_us"],
        "adc_time": adc,
        "adc_time_bound": bound,
        "fuzz": fz,
        "sim_per_wall": plain["sim_per_wall"],
        "sim_per_wall_profiled": prof["sim_per_wall"],
        "host_sim_per_wall": round(plain["sim_s"] / plain["host_wall_s"], 3),
        "events_lost": plain["events_lost"],
        "supervisor": sup,
    }
    report["ok"] = bool(size["flash_pct"] <= 50 and size["ram_pct"] <= 60 and worst_isr <= ISR_TARGET_CYCLES
                        and adc["max_abs_us"] is not None and adc["max_abs_us"] <= ADC_TARGET_US
                        and adc["input_max_abs_us"] is not None and adc["input_max_abs_us"] <= ADC_TARGET_US
                        and bool(adc["input_lossless"])
                        and all(r["v2_accepted"] == 0 for r in fz) and sup["ok"])
    if args.json:
        print(json.dumps(report, indent=2))
        return 0 if report["ok"] else 1
    print(f"flash  {size['flash_bytes']:6d} B  {size['flash_pct']:5.1f} %   (target <= 50 %)")
    print(f"RAM    {size['ram_bytes']:6d} B  {size['ram_pct']:5.1f} %   (target <= 60 %, static)")
    print(f"ISR cycles, interrupt to end of RETI (target <= {ISR_TARGET_CYCLES}); measured over "
          f"{args.seconds:g} simulated s, static = longest path in the code:")
    for name, s in isr.items():
        st = s["static_worst_cycles"]
        flag = "" if max(s["max_cycles"], st or 0) <= ISR_TARGET_CYCLES else "   <-- over target"
        print(f"  {name:12s} n={s['count']:6d}  mean {s['mean_cycles']:6.1f}  max {s['max_cycles']:4d}"
              f"  ({s['max_us']:.2f} us)  static {st if st is not None else 'loop':>4}{flag}")
    print(f"ISR worst case:                  {worst_isr} cycles ({worst_isr / 16:.2f} us)")
    print(f"longest cli window in main code: {report['cli_max_cycles_main']} cycles")
    print(f"longest I2C clock stretch:       {report['i2c_stretch_max_us']:.2f} us")
    print(f"ADC time vs the harness's conversions ({adc['conversions']} in {args.adc_seconds:g} s at "
          f"15,000/14,000 rpm, ringing, spikes): worst {adc['max_abs_us']:.2f} us, mean {adc['mean_us']:.2f} us "
          f"(target <= {ADC_TARGET_US:g})")
    print(f"input torque ADC (second AD7171, D8/D9): {adc['input_conversions']} conversions, "
          f"{'lossless' if adc['input_lossless'] else 'NOT LOSSLESS'} (each its own code), RDY time worst "
          f"{adc['input_max_abs_us']:.2f} us, mean {adc['input_mean_us']:.2f} us (target <= {ADC_TARGET_US:g})")
    print(f"  bound from the code: {bound['us']:.2f} us after RDY ({bound['cycles']} cycles), "
          f"{bound['harness_scale_us']:.2f} us on the harness's scale (zero = a Hall ISR's entry)")
    if fz:
        print(f"fuzz, {args.fuzz_frames:,} frames per bit-error rate (false accepts = corrupted frames accepted):")
        print(f"  {'BER':>8} {'v2 corrupted':>13} {'v2 accepted':>12} {'v2 expected':>12} "
              f"{'v1 corrupted':>13} {'v1 accepted':>12}")
        for r in fz:
            print(f"  {r['ber']:>8.0e} {r['v2_corrupted']:>13,} {r['v2_accepted']:>12} {r['v2_expected']:>12.1e} "
                  f"{r['v1_corrupted']:>13,} {r['v1_accepted']:>12}")
    print(f"simavr simulated/wall: {report['sim_per_wall']:.2f}x (harness), "
          f"{report['host_sim_per_wall']:.2f}x with the Python host; profiled {report['sim_per_wall_profiled']:.2f}x")
    hb, ov = sup["heartbeat"], sup["overspeed"]
    print(f"run-enable supervisor (D7), shipped limits (timeout {sup['timeout_s']:g} s, {ov['limit_rpm']:g} rpm):")
    print(f"  heartbeat: last poll -> off {_ms(hb['reaction_s'])} (cause {hb['cause']}; target <= {_ms(hb['bound_s'])}: "
          f"the timeout + a loop pass + the poll's transfer)")
    print(f"  over-speed at {ov['rpm']:g} rpm: first short period's end -> off {_ms(ov['reaction_s'])} (cause {ov['cause']}; "
          f"target <= {_ms(ov['bound_s'])}: the pulse's width {_ms(ov['pulse_width_s'])} + a loop pass); "
          f"speed above the limit -> off {_ms(ov['from_onset_s'])} (target <= {_ms(ov['onset_bound_s'])}: "
          f"2 periods at the limit + a loop pass)")
    print(f"  main-loop pass, longest (the old-bootloader build's pump interval): {sup['loop_pass_max_us']:.1f} us "
          f"(target < {sup['loop_pass_bound_us']:.0f} us), pump {'pulsing' if sup['pump_pulsing'] else 'NOT PULSING'}")
    print("all targets met" if report["ok"] else "TARGET MISSED")
    return 0 if report["ok"] else 1


def _ms(x) -> str:
    return "n/a" if x is None else f"{1e3 * x:.3f} ms"


if __name__ == "__main__":
    sys.exit(main())
