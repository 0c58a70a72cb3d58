"""Firmware in the loop (``dyno firmware-sim``, :mod:`dyno.cli.firmware_sim_cmd` its command line): run the real
firmware ELF in simavr against the real host code.  Library code: :func:`simulate` takes a
:class:`FirmwareSimSpec` and returns the report dictionary.

The harness emulates the rig around the MCU (Hall sensors, AD7171, the Pi's I2C
master); the host side is exactly what ``dyno run`` uses: ``make_reader`` from
``dyno.acquisition.reader`` over a :class:`~dyno.transports.simavr.SimavrTransport`,
polled at 150 Hz of simulated time.  At the end the generators stop and the host keeps
polling until the device's queue is empty, so every edge and conversion the harness
generated can be counted against what the host decoded.

v2: the host arms the Nano's run-enable supervisor at every boot with the rig file's limits and the
report says when the output (D7) went on and off and why (``supervisor``; issue 37,
:mod:`dyno.session.firmware_sim_supervisor`); ``--host-stop-at S`` stops the host's polls at S s.

The command's exit status: 0 when the run completed (v2/v1: and nothing was lost; with ``--host-stop-at``, whose stop
overflows the device's queue on purpose: and every event is either delivered or counted lost by the
device), 1 otherwise; 2 when the device speaks another protocol version than ``--protocol``. The
run-enable going off is not a failure by itself.
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass

import numpy as np

from dyno.acquisition.reader import make_reader
from dyno.errors import ConfigError
from dyno.acquisition.rpm import rpm_by_pairs
from dyno.protocol import v1
from dyno.protocol.v2 import CH_INPUT, CH_SUPERVISOR
from dyno.protocol.v2 import cause_name
from dyno.transports.simavr import ALL_FAULT_KINDS, FAULT_KINDS, SimavrSerialTransport, SimavrTransport
from dyno.session import firmware_sim_supervisor as supervisor


#: MCUSR bits the harness sets for a reset at ``reset_at`` (S, CAUSE)
RESET_CAUSES = {"watchdog": 0x08, "external": 0x02, "brown-out": 0x04}


@dataclass(frozen=True)
class FirmwareSimSpec:
    """One firmware-in-the-loop session (the command line's options, by the same names)."""

    elf: str
    protocol: str = "v2"  # v2 | v1 | v0
    transport: str = "i2c"  # the host's link to the MCU: "i2c" (TWI) or "serial" (UART0, COBS)
    primary_rpm: float = 3800.0
    secondary_rpm: float = 7600.0
    adc_code: int = 35145
    adc_status: int = 0x05  # AD7171 status byte clocked after the data
    adc_error_every: int = 0  # the AD7171 error bit on every Nth conversion (0: never)
    adc_hz: float = 125.0
    input_hz: float = 0.0  # the engine-side input torque AD7171 at this rate (0: not fitted)
    seconds: float = 5.0  # simulated seconds of signal
    bounce: bool = False  # the Hall line rings at release: two 40 us pulses 150 and 700 us after each pulse
    glitch_hz: float = 0.0  # Poisson rate of glitches on each Hall line, per second
    glitch_us: float = 20.0
    fault_rate: float = 0.0  # probability that a transfer is corrupted between harness and host
    fault_kinds: str = ",".join(FAULT_KINDS)  # comma list from ALL_FAULT_KINDS
    seed: int = 1
    poll_hz: float = 150.0
    poll_jitter: float = 0.0  # each poll interval uniform within +-J of the period (0 <= J < 1)
    max_burst: int = 8  # reads per poll while the device says MORE (the Poller's default)
    i2c_khz: int = 100
    drain_s: float = 0.3  # keep polling this long after the signals stop
    reset_at: tuple = ()  # ((seconds, MCUSR), ...): MCU resets (RESET_CAUSES)
    harness: str | None = None  # harness binary (None: firmware/build/harness)
    rig: object = None  # the rig file whose [limits] arm the run-enable at every boot (None: the default)
    host_stop_at: float | None = None  # the host stops polling at S simulated seconds
    rearm_at: float | None = None  # the operator re-arms the run-enable at S simulated seconds (issue 49)
    pulse_at: float | None = None  # the host's kill-path probe: PULSE_RUN_ENABLE at S simulated seconds (issue 49)
    pulse_ms: int = 100  # ... of this many ms
    no_limits: bool = False  # never send the limits (SET_SUPERVISOR): the run-enable stays off
    enable_model: str = "auto"  # how the harness reads D7: auto | static | pump


def check_spec(args: FirmwareSimSpec) -> tuple:
    """Bad arguments: one line naming the option (before anything else, the ELF included); the fault kinds."""
    if not 0.0 <= args.poll_jitter < 1.0:
        raise ConfigError("command line", "--poll-jitter", f"{args.poll_jitter} is outside 0 <= J < 1")
    kinds = tuple(k for k in args.fault_kinds.split(",") if k)
    bad = [k for k in kinds if k not in ALL_FAULT_KINDS]
    if bad:
        raise ConfigError("command line", "--fault-kinds", f"{','.join(bad)} unknown; expected a comma list "
                                                         f"from {','.join(ALL_FAULT_KINDS)}")
    if args.transport == "serial" and args.fault_rate:
        raise ConfigError("command line", "--fault-rate", "fault injection is for --transport i2c only")
    return kinds


def simulate(args: FirmwareSimSpec) -> dict:
    """Run one firmware-in-the-loop session (``args``: the spec); returns the report dictionary."""
    wall0 = time.perf_counter()
    kinds = check_spec(args)
    kw = dict(harness=args.harness, primary_rpm=args.primary_rpm,
              secondary_rpm=args.secondary_rpm, adc_code=args.adc_code,
              adc_status=args.adc_status, adc_error_every=args.adc_error_every,
              adc_hz=args.adc_hz, bounce=args.bounce, input_hz=args.input_hz, i2c_khz=args.i2c_khz,
              glitch_hz=args.glitch_hz, glitch_us=args.glitch_us,
              fault_rate=args.fault_rate, fault_kinds=kinds, seed=args.seed,
              enable_model=args.enable_model)
    sup = supervisor.SupervisorHost(args) if args.protocol == "v2" else None
    # The host's own transports: I2C (one combined transaction per poll) or USB serial
    # (COBS packets, dyno.transports.serial) wired to the MCU's UART.
    tr = SimavrSerialTransport(args.elf, **kw) if args.transport == "serial" else SimavrTransport(args.elf, **kw)
    try:
        reader = make_reader(args.protocol, tr, supervisor_command=sup.command if sup else None,
                             want_input=args.input_hz > 0)  # as a rig.toml with [input_torque]
        times = {v1.CH_PRIMARY: [], v1.CH_SECONDARY: [], v1.CH_ADC: [], CH_INPUT: []}
        input_codes: list = []
        gaps = {v1.CH_PRIMARY: [], v1.CH_SECONDARY: []}  # per edge: its period spans lost events
        pending = {v1.CH_PRIMARY: True, v1.CH_SECONDARY: True}
        codes, statuses, slot_rpm = [], [], {v1.CH_PRIMARY: [], v1.CH_SECONDARY: []}
        dt = 1.0 / args.poll_hz
        # Poll instants: regular, or with --poll-jitter J each interval uniform in
        # [(1-J), (1+J)] x the period (a loaded host), seeded.
        jitter_rng = random.Random(args.seed + 7919)
        t_next = 0.0
        reset_times = sorted(args.reset_at or [])
        # The signals start 50 ms after power-up; they run for args.seconds.
        t_stop = 0.05 + args.seconds
        t_end = t_stop + args.drain_s
        # a host stopped before the end comes back after the drain, for one more drain (its events)
        t_final = t_end + (args.drain_s if sup and sup.stop_at is not None and sup.stop_at <= t_end else 0.0)
        stopped = False
        first_frame_s = None  # poll time of the first accepted frame
        while True:
            t = t_next
            t_next += dt * (1.0 + args.poll_jitter * (2.0 * jitter_rng.random() - 1.0))
            if t > t_final:
                break
            if not stopped and t >= t_stop:
                tr.advance_to(t_stop)
                tr.generators(False)
                stopped = True
            while reset_times and t >= reset_times[0][0]:
                at, mcusr = reset_times.pop(0)
                tr.advance_to(at)
                tr.reset_device(mcusr)
            tr.advance_to(t)
            if sup and not sup.polling(t, t_end):
                continue  # --host-stop-at: the simulation goes on, the host does not poll
            if sup:  # --rearm-at: the operator's re-arm (the only way a new boot is armed again); --pulse-at
                sup.maybe_rearm(reader, t)
                sup.maybe_pulse(reader, t)
            for _ in range(args.max_burst):  # as the Poller: read again at once while the device says MORE
                resets_before = reader.stats.device_resets
                new = reader.poll(t)
                if sup:  # the limits to a new boot; the tag-5 events noted
                    sup.after_poll(reader, t, new)
                if first_frame_s is None and reader.stats.accepted:
                    first_frame_s = t
                if reader.stats.device_resets != resets_before:  # never a period across a reset
                    pending = dict.fromkeys(pending, True)
                for ev in new:
                    if ev.gap:
                        pending = dict.fromkeys(pending, True)
                    if ev.channel == CH_SUPERVISOR:
                        continue  # (the supervisor's report has them)
                    if ev.channel in gaps:
                        gaps[ev.channel].append(pending[ev.channel])
                        pending[ev.channel] = False
                    times[ev.channel].append(ev.t_us)
                    if ev.channel == v1.CH_ADC:
                        codes.append(ev.code)
                        statuses.append(ev.status)
                    elif ev.channel == CH_INPUT:
                        input_codes.append(ev.code)
                    elif args.protocol == "v0":
                        slot_rpm[ev.channel].append(ev.code)
                if not reader.more:
                    break
        info = reader.read_info() if args.protocol != "v0" else None
        hs = tr.harness_stats()
        faults = dict(tr.faults_injected)
    finally:
        tr.close()
    out = _report(args, reader, times, gaps, codes, statuses, slot_rpm, info, hs, faults,
                  time.perf_counter() - wall0)
    out["first_frame_s"] = first_frame_s
    if sup:
        out["supervisor"] = supervisor.report(sup, hs, first_frame_s)
        if sup.stop_at is not None:  # the stop overflows the queue on purpose: exact accounting instead
            out["ok"] = bool(not hs["crashed"] and not hs.get("ring_guard", {}).get("violations")
                             and out["accounting"]["exact"]
                             and all(ch["duplicates_or_disorder"] == 0 for ch in out["events"].values()))
    if args.input_hz > 0:
        out["input"] = _input_report(reader, times, input_codes, hs)
    return out


def _input_report(reader, times, codes, hs) -> dict:
    """The input torque converter: enabled, lossless (every conversion the device read after the
    enable, each its own code), and its timestamps against the harness's RDY edges."""
    h = hs.get("input") or {}
    t = times[CH_INPUT]
    period = h.get("period_us") or 0.0
    err = None
    if t and period:
        # on the harness's clock as the brake-side ADC's times are (the primary Hall edges' offset)
        hall, tp = hs["hall"][0], times[v1.CH_PRIMARY]
        if len(tp) >= 2 and hall.get("rpm"):
            pp = 60e6 / hall["rpm"]
            d = np.asarray(tp, dtype=float)
            offset = float(np.median(d - hall["first_us"] - np.round((d - d[0]) / pp) * pp))
            x = np.asarray(t, dtype=float) - offset - h["rdy_t0_us"]
            e = x - np.round(x / period) * period
            err = {"max_abs_us": float(np.max(np.abs(e))), "mean_us": float(np.mean(e))}
    c = np.asarray(codes, dtype=np.int64)
    steps = np.diff(c) % 4096 if c.size > 1 else np.zeros(0, dtype=np.int64)
    return {"present": reader.input_present, "received": len(t), "generated": h.get("generated"),
            "read_by_device": h.get("read"), "missed_by_device": h.get("missed"),
            "distinct_codes_consecutive": bool(steps.size == 0 or np.all(steps == 1)),
            "first_code": int(c[0]) if c.size else None, "time_error_us": err}


def _channel(ts) -> dict:
    t = np.asarray(ts, dtype=np.int64)
    d = np.diff(t) if t.size > 1 else np.zeros(0, dtype=np.int64)
    return {
        "received": int(t.size),
        "duplicates_or_disorder": int(np.count_nonzero(d <= 0)),
        "period_min_us": int(d.min()) if d.size else None,
        "period_max_us": int(d.max()) if d.size else None,
    }


def _adc_time_error(times, hs) -> dict | None:
    """ADC timestamps against the harness's RDY falling edges (us). The device clock is put
    on the harness's by the primary Hall edges (median offset; the Hall ISR's latency is
    similar to the RDY ISR's, so what remains is the extra latency of the ADC time)."""
    adc, hall = hs["adc"], hs["hall"][0]
    t_adc, t_p = times[v1.CH_ADC], times[v1.CH_PRIMARY]
    if not t_adc or len(t_p) < 2 or not adc.get("period_us") or not hall.get("rpm"):
        return None
    period_p = 60e6 / hall["rpm"]
    d = np.asarray(t_p, dtype=float)
    k = np.round((d - d[0]) / period_p)
    offset = float(np.median(d - hall["first_us"] - k * period_p))  # device minus harness time
    t = np.asarray(t_adc, dtype=float) - offset - adc["rdy_t0_us"]
    err = t - np.round(t / adc["period_us"]) * adc["period_us"]
    return {"max_abs_us": float(np.max(np.abs(err))), "mean_us": float(np.mean(err))}


def _hall_edge_error(times, hs) -> dict | None:
    """Each channel's received Hall edges against the harness's true falling edges (us), on the
    harness's clock (the primary edges' median offset, as for the ADC): ``off_edge`` counts events
    more than 100 us from any true edge (a spike or a ringing pulse taken for an edge; a real edge
    is late by its ISR latency, or early by at most a spike merged into its start), ``max_abs_us``
    is the worst of the others."""
    hall = hs["hall"]
    t_p = times[v1.CH_PRIMARY]
    if len(t_p) < 2 or not hall[0].get("rpm"):
        return None
    period_p = 60e6 / hall[0]["rpm"]
    d = np.asarray(t_p, dtype=float)
    offset = float(np.median(d - hall[0]["first_us"] - np.round((d - d[0]) / period_p) * period_p))
    out = {}
    for c, (name, ch) in enumerate((("primary", v1.CH_PRIMARY), ("secondary", v1.CH_SECONDARY))):
        if not times[ch] or not hall[c].get("rpm"):
            continue
        period = 60e6 / hall[c]["rpm"]
        x = np.asarray(times[ch], dtype=float) - offset - hall[c]["first_us"]
        e = x - np.round(x / period) * period
        off = np.abs(e) > 100.0
        out[name] = {"off_edge": int(np.count_nonzero(off)),
                     "max_abs_us": float(np.max(np.abs(e[~off]))) if np.any(~off) else None}
    return out


def _accounting(events: dict, lost: int) -> dict:
    generated = (events["primary"]["expected"] + events["secondary"]["expected"]
                 + events["adc"]["read_by_device"])
    delivered = sum(ch["received"] for ch in events.values())
    return {"generated": generated, "delivered": delivered, "reported_lost": lost,
            "exact": delivered + lost == generated}


def _report(args: FirmwareSimSpec, reader, times, gaps, codes, statuses, slot_rpm, info, hs, faults, wall_s) -> dict:
    # Mean rpm over adjacent edge pairs only: a period spanning lost events (v2 marks them)
    # or a reset is left out, never spread over.
    rp, n_p = rpm_by_pairs(times[v1.CH_PRIMARY], gaps[v1.CH_PRIMARY])
    rs, n_s = rpm_by_pairs(times[v1.CH_SECONDARY], gaps[v1.CH_SECONDARY])

    def err_pct(got, want):
        return None if not want or math.isnan(got) else 100.0 * (got - want) / want

    def num(x):
        return None if x is None or (isinstance(x, float) and math.isnan(x)) else x

    hall = hs["hall"]
    adc = hs["adc"]
    events = {
        "primary": {"expected": hall[0]["edges"], **_channel(times[v1.CH_PRIMARY])},
        "secondary": {"expected": hall[1]["edges"], **_channel(times[v1.CH_SECONDARY])},
        "adc": {"expected": adc["generated"], "read_by_device": adc["read"],
                **_channel(times[v1.CH_ADC])},
    }
    for ch in events.values():
        ch["missing"] = ch["expected"] - ch["received"]
    stats = reader.stats.as_dict()
    out = {
        "protocol": args.protocol,
        "transport": args.transport,
        "elf": str(args.elf),
        "seconds": args.seconds,
        "poll_hz": args.poll_hz,
        "rpm_primary": num(rp),
        "rpm_secondary": num(rs),
        "rpm_expected": {"primary": args.primary_rpm, "secondary": args.secondary_rpm},
        "rpm_error_pct": {"primary": num(err_pct(rp, args.primary_rpm)),
                          "secondary": num(err_pct(rs, args.secondary_rpm))},
        "adc_mean": float(np.mean(codes)) if codes else None,
        "adc_error_flags": int(sum(1 for s in statuses if s & v1.ADC_STATUS_ERR)),
        "frames": {
            "read": stats["read"],
            "accepted": stats["accepted"],
            "rejected": stats["rejected"],
            "rejected_total": stats["rejected_total"],
            "transport_errors": stats["transport_errors"],
            "device_resets": stats["device_resets"],
            "resyncs": stats["resyncs"],
        },
        "events_lost": reader.events_lost,
        "rpm_periods": {"primary": n_p, "secondary": n_s},
        # Loss accounting after the drain: every Hall pulse the harness generated and every
        # conversion the device read is either delivered or counted lost by the device.
        # (Events queued in the MCU at a reset vanish with its RAM: not exact across resets.)
        "accounting": _accounting(events, reader.events_lost),
        "adc_time_error_us": _adc_time_error(times, hs) if stats["device_resets"] == 0 else None,
        "hall_edge_error": _hall_edge_error(times, hs) if stats["device_resets"] == 0 else None,
        "events": events,
        "faults_injected": faults,
        "bounce": bool(args.bounce),
        "harness": {
            "bounce_edges": [hall[0]["bounce_edges"], hall[1]["bounce_edges"]],
            "glitches": [hall[0].get("glitches", 0), hall[1].get("glitches", 0)],
            "pulse_us": [hall[0].get("pulse_us"), hall[1].get("pulse_us")],
            "first_edge_us": [hall[0].get("first_us"), hall[1].get("first_us")],  # each channel's first true edge
            "adc_missed_by_device": adc["missed"],
            "i2c": hs["i2c"],
            # The ring's guard bytes, checked by the harness after every command: a write
            # outside the ring shows as a violation (null for sketches without the ring).
            "ring_guard": hs.get("ring_guard") if hs.get("ring_guard", {}).get("found") else None,
            # WDTCSR as the firmware left it: WDE (0x08) set = the watchdog resets the MCU.
            "watchdog_enabled": bool(hs.get("wdtcsr", 0) & 0x08),
            "eeprom_writes": hs.get("eeprom_writes"),
            "sim_s": hs["sim_s"],
            "sim_per_wall": hs["sim_per_wall"],
            "crashed": hs["crashed"],
        },
        "wall_s": round(wall_s, 3),
    }
    if args.protocol == "v0":
        out["rpm_slot_mean"] = {
            "primary": float(np.mean(slot_rpm[v1.CH_PRIMARY])) if slot_rpm[v1.CH_PRIMARY] else None,
            "secondary": float(np.mean(slot_rpm[v1.CH_SECONDARY])) if slot_rpm[v1.CH_SECONDARY] else None,
        }
    if info is not None:
        out["device"] = {"fw_version": ".".join(map(str, info.fw_version)), "uptime_ms": info.uptime_ms,
                         "debounce_primary_us": info.debounce_primary_us,
                         "debounce_secondary_us": info.debounce_secondary_us}
        if args.protocol == "v2":
            out["device"].update({"boot_id": info.boot_id, "reset_cause": cause_name(info.reset_cause),
                                  "run": bool(info.flags & 0x08),  # FLAG_RUN: the run-enable (D7) on
                                  "twi_timeouts": info.twi_timeouts, "bus_errors": info.bus_errors})
            out["edges_rejected"] = {
                name: {"lockout": info.lockout_rejected[k], "glitch": info.glitch_rejected[k]}
                for k, name in enumerate(("primary", "secondary"))}
        else:
            out["device"]["boot_count"] = info.boot_count
    if args.protocol == "v2":
        out["boots"] = stats["boots"]
    guard_ok = not hs.get("ring_guard", {}).get("violations")
    out["ok"] = bool(not hs["crashed"] and guard_ok and (args.protocol == "v0" or (
        reader.events_lost == 0 and all(ch["missing"] == 0 and ch["duplicates_or_disorder"] == 0
                                        for ch in events.values()))))
    return out
