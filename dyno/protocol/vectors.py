"""Golden test vectors shared by the host tests and the firmware's native tests.

``python -m dyno.protocol.vectors`` rewrites ``dyno/protocol/vectors/*.hex``
from the definitions below; a test checks that the files in the repository
match and that the decoder agrees with every line.

Line format (one vector per line, ``#`` comments), fields separated by spaces::

    crc  <data-hex> <crc16-hex>
    frame <name> seq=N flags=N dropped=N t0=N events=<ev>[,<ev>...] hex=<32 bytes>
        <ev> is  <ch>@<t_us>  or, for ADC,  3@<t_us>:<code>:<status>   ('-' for none)
    info <name> seq=N flags=N fw=A.B.C boots=N uptime_ms=N deb_p=N deb_s=N hex=<32 bytes>
    bad <name> cause=<cause> hex=<bytes>
    cmd <name> op=N args=<a>[,<b>...] hex=<bytes>      ('-' for no args)
    badcmd <name> cause=<cause> hex=<bytes>
    v0 <name> rp=N tp=N rs=N ts=N adc=N ta=N hex=<20 bytes>
    v0bad <name> cause=<cause> hex=<20 bytes>

``v2.hex`` uses the same kinds with v2 fields: ``crc32c <data-hex> <crc32c-hex>``,
``frame ... boot=N ...`` (flags include the reset cause in bits 4..7), ``info ... boot=N
lock=P,S glitch=P,S twi_timeouts=N bus_errors=N``, and ``cmd ... args=<boot>,<seq>``.
"""

from __future__ import annotations

from pathlib import Path

from dyno.protocol import v0, v1, v2
from dyno.protocol.crc import crc16, crc32c

VECTOR_DIR = Path(__file__).with_name("vectors")
E = v1.Event


def _ev(e: v1.Event) -> str:
    tag = e.channel | (v2.TAG_GAP if e.gap else 0)  # v2: the gap mark is the tag's bit 7
    return f"{tag}@{e.t_us}:{e.code}:{e.status}" if e.channel in v2.ADC_TAGS else f"{tag}@{e.t_us}"


def _frames():
    yield "empty", 0, 0, 0, [], 1_000_000
    yield "one_primary", 1, 0, 0, [E(1, 5_000_000)], 0
    yield "mixed_three", 2, 0, 0, [E(1, 5_000_000), E(2, 5_000_300), E(3, 5_001_000, 35145, 0x05)], 0
    yield "adc_error_bit", 3, 0, 0, [E(3, 7_000_000, 0xFFFF, v1.ADC_STATUS_ERR | 0x05)], 0
    yield "full_payload", 4, v1.FLAG_MORE, 0, [E(1, 10), E(2, 20), E(1, 30), E(2, 40), E(3, 50, 1234, 5)], 0
    yield "negative_dt", 5, 0, 0, [E(3, 9_000_500, 40000, 5), E(1, 9_000_400)], 0
    yield "wrap_2_32", 6, 0, 0, [E(1, 0xFFFFFF00), E(2, 0x00000040)], 0
    yield "reset_first", 0, v1.FLAG_RESET, 0, [E(2, 1234)], 0
    yield "overflow_dropped", 200, v1.FLAG_OVERFLOW | v1.FLAG_MORE, 513, [E(1, 123_456_789)], 0
    yield "seq_255", 255, 0, 65535, [E(2, 0x7FFFFFFF), E(2, 0x80000000 + 0x7000)], 0


def _bad():
    good = bytearray(v1.encode_data_frame(2, 0, 0, [E(1, 5_000_000), E(2, 5_000_300)]))
    yield "all_zero", "all_zero", bytes(32)
    yield "all_ff", "all_ff", b"\xff" * 32
    yield "short", "short", bytes(good[:10])
    flip = bytearray(good); flip[12] ^= 0x01
    yield "crc_bitflip", "crc", bytes(flip)
    ver = bytearray(good); ver[0] = 2
    yield "version", "version", bytes(ver)
    ln = bytearray(good); ln[1] = 33
    yield "length", "length", bytes(ln)
    pad = bytearray(good); pad[31] = 0x01
    yield "padding", "padding", bytes(pad)
    body = bytes([1, 14, 0x44, 9, 0, 0, 0, 0, 0, 0, 0, 0x07])
    tag = body + crc16(body).to_bytes(2, "big")
    yield "event_tag", "event_tag", tag.ljust(32, b"\0")
    body = bytes([1, 13, 0x58, 9, 0, 0, 0, 0, 0, 0, 0])
    yield "kind", "kind", (body + crc16(body).to_bytes(2, "big")).ljust(32, b"\0")
    body = bytes([1, 13, 0x44, 9, 0x80, 0, 0, 0, 0, 0, 0])
    yield "flags", "flags", (body + crc16(body).to_bytes(2, "big")).ljust(32, b"\0")


def _cmds():
    yield "poll", v1.OP_POLL, ()
    yield "ack_poll_0", v1.OP_ACK_POLL, (0,)
    yield "ack_poll_255", v1.OP_ACK_POLL, (255,)
    yield "set_debounce_thesis", v1.OP_SET_DEBOUNCE, (10000, 6000)
    yield "clear_counters", v1.OP_CLEAR_COUNTERS, ()
    yield "info", v1.OP_INFO, ()


def _v0():
    yield "thesis_like", v0.LegacyFrame(3089, 93488228, 4926, 93493780, 35911, 93496148)
    yield "zero_rpm_start", v0.LegacyFrame(100, 0, 100, 0, 35145, 1000)
    yield "max_values", v0.LegacyFrame(65535, 0xFFFFFFFE, 65535, 0xFFFFFFFE, 65535, 0xFFFFFFFE)


def _frames_v2():
    por = v2.CAUSE_PORF << v2.CAUSE_SHIFT
    wdt = v2.CAUSE_WDRF << v2.CAUSE_SHIFT
    yield "empty_first", 0, v2.FLAG_RESET | por, 1, 0, [], 1_000_000
    yield "one_primary", 1, por, 1, 0, [E(1, 5_000_000)], 0
    yield "mixed_three", 2, por, 1, 0, [E(1, 5_000_000), E(2, 5_000_300), E(3, 5_001_000, 35145, 0x05)], 0
    yield "adc_error_bit", 3, por, 2, 0, [E(3, 7_000_000, 0xFFFF, v1.ADC_STATUS_ERR | 0x05)], 0
    yield "full_payload", 4, v2.FLAG_MORE | por, 2, 0, [E(1, 10), E(2, 20), E(1, 30), E(2, 40), E(1, 50)], 0
    yield "adc_plus_three", 5, por, 2, 0, [E(1, 10), E(3, 15, 1234, 5), E(2, 20), E(1, 30)], 0
    yield "negative_dt", 6, por, 0x1234, 0, [E(3, 9_000_500, 40000, 5), E(1, 9_000_400)], 0
    yield "wrap_2_32", 7, por, 0xFFFF, 0, [E(1, 0xFFFFFF00), E(2, 0x00000040)], 0
    yield "watchdog_boot", 0, v2.FLAG_RESET | wdt, 3, 0, [E(2, 1234)], 0
    yield "ext_brownout_boot", 0, v2.FLAG_RESET | ((v2.CAUSE_EXTRF | v2.CAUSE_BORF) << 4), 4, 0, [], 77
    yield "overflow_dropped", 200, v2.FLAG_OVERFLOW | v2.FLAG_MORE | wdt, 9, 513, [E(1, 123_456_789)], 0
    yield "seq_255", 255, wdt, 0x8000, 65535, [E(2, 0x7FFFFFFF), E(2, 0x80000000 + 0x7000)], 0
    yield "gap_marks", 17, v2.FLAG_OVERFLOW | wdt, 9, 40, [E(1, 1000), E(2, 1200, gap=True),
                                                           E(3, 1300, 321, 5, gap=True)], 0


def _bad_v2():
    good = bytearray(v2.encode_data_frame(2, 0, 7, 0, [E(1, 5_000_000), E(2, 5_000_300)]))
    yield "all_zero", "all_zero", bytes(32)
    yield "all_ff", "all_ff", b"\xff" * 32
    yield "short", "short", bytes(good[:16])
    flip = bytearray(good); flip[14] ^= 0x01
    yield "crc_bitflip", "crc", bytes(flip)
    ver = bytearray(good); ver[0] = 3
    yield "version", "version", bytes(ver)
    ln = bytearray(good); ln[1] = 33
    yield "length", "length", bytes(ln)
    pad = bytearray(good); pad[31] = 0x01
    yield "padding", "padding", bytes(pad)

    def sealed(body):
        return (body + crc32c(body).to_bytes(4, "big")).ljust(32, b"\0")
    yield "event_tag", "event_tag", sealed(bytes([2, 18, 0x44, 9, 0, 0, 7, 0, 0, 0, 0, 0, 0, 0x07]))
    yield "kind", "kind", sealed(bytes([2, 17, 0x58, 9, 0, 0, 7, 0, 0, 0, 0, 0, 0]))
    # (no "flags" vector: bit 3, the last spare one, is the run-enable's RUN since issue 37)
    yield "event_length", "event_length", sealed(bytes([2, 19, 0x44, 9, 0, 0, 7, 0, 0, 0, 0, 0, 0, 1, 0]))


def _cmds_v2():
    yield "poll", v2.OP_POLL, ()
    yield "ack_poll_1_0", v2.OP_ACK_POLL, (1, 0)
    yield "ack_poll_ffff_255", v2.OP_ACK_POLL, (0xFFFF, 255)
    yield "set_debounce_thesis", v2.OP_SET_DEBOUNCE, (10000, 6000)
    yield "clear_counters", v2.OP_CLEAR_COUNTERS, ()
    yield "info", v2.OP_INFO, ()


def render_v2() -> str:
    lines = ["# Protocol v2 golden vectors (generated by python -m dyno.protocol.vectors).",
             "# Format: see dyno/protocol/vectors.py and docs/protocol.md."]
    for data in (b"123456789", b"", b"\x00", b"\x02\x11\x44"):
        lines.append(f"crc32c {data.hex() or '-'} {crc32c(data):08x}")
    for name, seq, flags, boot, dropped, events, now in _frames_v2():
        raw = v2.encode_data_frame(seq, flags, boot, dropped, events, now)
        t0 = events[0].t_us if events else now
        evs = ",".join(_ev(e) for e in events) or "-"
        lines.append(f"frame {name} seq={seq} flags={flags} boot={boot} dropped={dropped} t0={t0} "
                     f"events={evs} hex={raw.hex()}")
    info = v2.InfoFrame(7, v2.CAUSE_WDRF << 4, 3, (2, 0, 0), 123456, 10000, 6000, (11, 22), (333, 4444), 5, 250)
    lines.append(f"info fw_2_0_0 seq=7 flags={info.flags} boot=3 fw=2.0.0 uptime_ms=123456 deb_p=10000 "
                 f"deb_s=6000 lock=11,22 glitch=333,4444 twi_timeouts=5 bus_errors=250 "
                 f"hex={v2.encode_info_frame(info).hex()}")
    for name, cause, raw in _bad_v2():
        lines.append(f"bad {name} cause={cause} hex={raw.hex()}")
    for name, op, args in _cmds_v2():
        raw = v2.encode_command(op, *args)
        lines.append(f"cmd {name} op={op} args={','.join(map(str, args)) or '-'} hex={raw.hex()}")
    good = v2.encode_command(v2.OP_ACK_POLL, 1, 5)
    lines.append(f"badcmd crc cause=crc hex={(good[:-1] + bytes([good[-1] ^ 0x80])).hex()}")
    lines.append(f"badcmd unknown_op cause=op hex={bytes([0x77, 0, 0]).hex()}")
    lines.append(f"badcmd wrong_length cause=length hex={good.hex() + '00'}")
    lines.append(f"badcmd v1_ack_poll cause=length hex={v1.encode_command(v1.OP_ACK_POLL, 5).hex()}")
    return "\n".join(lines) + "\n"


def render_v2_input() -> str:
    """The input-channel extension of v2 (issue 27): tag 4 events, CAPS / SET_CHANNELS, the capabilities frame.

    A file of its own, so the firmware's native test of ``v2.hex`` holds for firmware built without it.
    ``caps <name> seq=N flags=N boot=N channels=N enabled=N converter=N rate_mhz=N hex=<32 bytes>``.
    """
    por = v2.CAUSE_PORF << v2.CAUSE_SHIFT
    lines = ["# Protocol v2 input-channel extension vectors (generated by python -m dyno.protocol.vectors).",
             "# Format: see dyno/protocol/vectors.py and docs/protocol.md (Input torque channel)."]
    frames = (
        ("input_one", 20, por, 5, 0, [E(4, 2_000_000, 36000, 5)], 0),
        ("both_adcs", 21, por, 5, 0, [E(3, 2_000_000, 35145, 5), E(4, 2_000_900, 30001, 5), E(1, 2_001_000)], 0),
        ("input_error_bit", 22, por, 5, 0, [E(4, 2_100_000, 0xFFFF, v1.ADC_STATUS_ERR | 5)], 0),
        ("input_gap_negative_dt", 23, v2.FLAG_OVERFLOW | por, 5, 3,
         [E(4, 9_000_500, 40000, 5, gap=True), E(2, 9_000_400)], 0),
    )
    for name, seq, flags, boot, dropped, events, now in frames:
        raw = v2.encode_data_frame(seq, flags, boot, dropped, events, now)
        t0 = events[0].t_us if events else now
        lines.append(f"frame {name} seq={seq} flags={flags} boot={boot} dropped={dropped} t0={t0} "
                     f"events={','.join(_ev(e) for e in events)} hex={raw.hex()}")
    for name, caps in (("fitted_off", v2.CapsFrame(0, por, 5, v2.CHANNEL_INPUT, 0,
                                                    v2.CONVERTER_AD7171, 125_000)),
                       ("fitted_on", v2.CapsFrame(3, por, 5, v2.CHANNEL_INPUT, v2.CHANNEL_INPUT,
                                                  v2.CONVERTER_AD7171, 125_000)),
                       ("absent", v2.CapsFrame(1, por, 6, 0, 0, v2.CONVERTER_NONE, 0))):
        lines.append(f"caps {name} seq={caps.seq} flags={caps.flags} boot={caps.boot_id} channels={caps.channels} "
                     f"enabled={caps.enabled} converter={caps.input_converter} rate_mhz={caps.input_rate_mhz} "
                     f"hex={v2.encode_caps_frame(caps).hex()}")
    for name, op, args in (("caps", v2.OP_CAPS, ()), ("set_channels_input", v2.OP_SET_CHANNELS, (1,)),
                           ("set_channels_none", v2.OP_SET_CHANNELS, (0,))):
        raw = v2.encode_command(op, *args)
        lines.append(f"cmd {name} op={op} args={','.join(map(str, args)) or '-'} hex={raw.hex()}")
    return "\n".join(lines) + "\n"


def render_v2_supervisor() -> str:
    """The run-enable supervisor's extension of v2 (issue 37): flag RUN, tag 5 events, SET_SUPERVISOR and the
    capabilities frame's supervisor bit.  A file of its own, as ``v2-input.hex``."""
    por, wdr = v2.CAUSE_PORF << v2.CAUSE_SHIFT, v2.CAUSE_WDRF << v2.CAUSE_SHIFT
    run = v2.FLAG_RUN
    lines = ["# Protocol v2 run-enable supervisor vectors (generated by python -m dyno.protocol.vectors).",
             "# Format: see dyno/protocol/vectors.py and docs/protocol.md (Run-enable supervisor)."]
    frames = (
        ("sup_on", 1, por | run, 7, 0, [E(5, 1_000_000, 0, v2.SUP_ON), E(1, 1_000_500)], 0),
        ("sup_heartbeat", 9, por, 7, 0, [E(1, 3_000_000), E(5, 3_000_200, 200, v2.SUP_HEARTBEAT)], 0),
        ("sup_overspeed_primary", 10, wdr, 8, 0,
         [E(1, 4_000_000), E(1, 4_013_000), E(5, 4_013_000, 13000, v2.SUP_OVERSPEED_PRIMARY)], 0),
        ("sup_overspeed_secondary_gap", 11, v2.FLAG_OVERFLOW | por, 7, 2,
         [E(5, 5_000_000, 7600, v2.SUP_OVERSPEED_SECONDARY, gap=True)], 0),
        ("run_empty", 12, por | run | v2.FLAG_RESET, 7, 0, [], 6_000_000),
        # the kill-path probe (issue 49): off for a 100 ms pulse (no RUN while it lasts), on again at its end
        ("sup_pulse", 13, por, 7, 0, [E(5, 7_000_000, 100, v2.SUP_PULSE), E(1, 7_020_000)], 0),
        ("sup_pulse_end", 14, por | run, 7, 0, [E(1, 7_090_000), E(5, 7_100_000, 0, v2.SUP_ON)], 0),
    )
    for name, seq, flags, boot, dropped, events, now in frames:
        raw = v2.encode_data_frame(seq, flags, boot, dropped, events, now)
        t0 = events[0].t_us if events else now
        lines.append(f"frame {name} seq={seq} flags={flags} boot={boot} dropped={dropped} t0={t0} "
                     f"events={','.join(_ev(e) for e in events) or '-'} hex={raw.hex()}")
    both = v2.CHANNEL_INPUT | v2.CHANNEL_SUPERVISOR
    for name, caps in (("supervisor_unarmed", v2.CapsFrame(0, por, 7, v2.CHANNEL_SUPERVISOR, 0, v2.CONVERTER_NONE, 0)),
                       ("supervisor_armed", v2.CapsFrame(2, por, 7, v2.CHANNEL_SUPERVISOR, v2.CHANNEL_SUPERVISOR,
                                                         v2.CONVERTER_NONE, 0)),
                       ("input_and_supervisor", v2.CapsFrame(4, wdr, 8, both, both, v2.CONVERTER_AD7171, 125_000))):
        lines.append(f"caps {name} seq={caps.seq} flags={caps.flags} boot={caps.boot_id} channels={caps.channels} "
                     f"enabled={caps.enabled} converter={caps.input_converter} rate_mhz={caps.input_rate_mhz} "
                     f"hex={v2.encode_caps_frame(caps).hex()}")
    info = v2.InfoFrame(5, por | run, 7, (2, 1, 0), 123_456, 1000, 1000, (3, 4), (1, 2), 0, 0)
    lines.append(f"info run_on seq=5 flags={info.flags} boot=7 fw=2.1.0 uptime_ms=123456 deb_p=1000 deb_s=1000 "
                 f"lock=3,4 glitch=1,2 twi_timeouts=0 bus_errors=0 hex={v2.encode_info_frame(info).hex()}")
    for name, args in (("set_supervisor_shipped", (v2.min_period_us(4200.0), v2.min_period_us(7800.0), 200)),
                       ("set_supervisor_primary_only", (v2.min_period_us(4200.0), 0, 65535))):
        raw = v2.encode_command(v2.OP_SET_SUPERVISOR, *args)
        lines.append(f"cmd {name} op={v2.OP_SET_SUPERVISOR} args={','.join(map(str, args))} hex={raw.hex()}")
    for name, ms in (("pulse_run_enable_100", 100), ("pulse_run_enable_max", v2.PULSE_MS_MAX),
                     ("pulse_run_enable_latch", v2.PULSE_LATCH)):
        raw = v2.pulse_command(ms)
        lines.append(f"cmd {name} op={v2.OP_PULSE_RUN_ENABLE} args={ms} hex={raw.hex()}")
    good = v2.encode_command(v2.OP_SET_SUPERVISOR, 14285, 7692, 200)
    lines.append(f"badcmd supervisor_crc cause=crc hex={(good[:-1] + bytes([good[-1] ^ 0x01])).hex()}")
    lines.append(f"badcmd supervisor_short cause=length hex={(good[:-3] + good[-2:]).hex()}")
    good = v2.pulse_command(100)
    lines.append(f"badcmd pulse_crc cause=crc hex={(good[:-1] + bytes([good[-1] ^ 0x01])).hex()}")
    return "\n".join(lines) + "\n"


def render() -> dict[str, str]:
    lines = ["# Protocol v1 golden vectors (generated by python -m dyno.protocol.vectors).",
             "# Format: see dyno/protocol/vectors.py and docs/protocol.md."]
    for data in (b"123456789", b"", b"\x00", b"\x01\x0e\x44"):
        lines.append(f"crc {data.hex() or '-'} {crc16(data):04x}")
    for name, seq, flags, dropped, events, now in _frames():
        raw = v1.encode_data_frame(seq, flags, dropped, events, now)
        t0 = events[0].t_us if events else now
        evs = ",".join(_ev(e) for e in events) or "-"
        lines.append(f"frame {name} seq={seq} flags={flags} dropped={dropped} t0={t0} events={evs} hex={raw.hex()}")
    info = v1.InfoFrame(7, 0, (1, 0, 0), 42, 123456, 10000, 6000)
    lines.append(f"info fw_1_0_0 seq=7 flags=0 fw=1.0.0 boots=42 uptime_ms=123456 deb_p=10000 deb_s=6000 "
                 f"hex={v1.encode_info_frame(info).hex()}")
    for name, cause, raw in _bad():
        lines.append(f"bad {name} cause={cause} hex={raw.hex()}")
    for name, op, args in _cmds():
        raw = v1.encode_command(op, *args)
        lines.append(f"cmd {name} op={op} args={','.join(map(str, args)) or '-'} hex={raw.hex()}")
    good = v1.encode_command(v1.OP_ACK_POLL, 5)
    lines.append(f"badcmd crc cause=crc hex={(good[:-1] + bytes([good[-1] ^ 0x80])).hex()}")
    lines.append(f"badcmd unknown_op cause=op hex={bytes([0x77, 0, 0]).hex()}")
    lines.append(f"badcmd wrong_length cause=length hex={good.hex() + '00'}")
    out = {"v1.hex": "\n".join(lines) + "\n"}
    lines = ["# Protocol v0 (thesis legacy 20-byte frame) golden vectors."]
    for name, f in _v0():
        lines.append(f"v0 {name} rp={f.rpm_primary} tp={f.t_primary_us} rs={f.rpm_secondary} "
                     f"ts={f.t_secondary_us} adc={f.adc_code} ta={f.t_adc_us} hex={v0.encode_legacy_frame(f).hex()}")
    good = bytearray(v0.encode_legacy_frame(v0.LegacyFrame(3089, 93488228, 4926, 93493780, 35911, 93496148)))
    bad = bytearray(good); bad[3] ^= 0x10
    lines.append(f"v0bad checksum cause=checksum hex={bytes(bad).hex()}")
    lines.append(f"v0bad all_zero cause=all_zero hex={bytes(20).hex()}")
    lines.append("v0bad all_ff cause=all_ff hex=" + "ff" * 20)
    out["v0.hex"] = "\n".join(lines) + "\n"
    out["v2.hex"] = render_v2()
    out["v2-input.hex"] = render_v2_input()
    out["v2-supervisor.hex"] = render_v2_supervisor()
    return out


def main() -> None:
    VECTOR_DIR.mkdir(exist_ok=True)
    for name, text in render().items():
        (VECTOR_DIR / name).write_text(text)
        print(f"wrote {VECTOR_DIR / name}")


if __name__ == "__main__":
    main()
