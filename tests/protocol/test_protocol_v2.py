"""Protocol v2: golden vectors, boot identity in frames and ACKs, reset cause, version mismatch."""

import random

import pytest

from dyno.acquisition.reader import make_reader
from dyno.errors import ConfigError, FrameError
from dyno.protocol import v0, v1, v2
from dyno.protocol.crc import crc32c
from dyno.protocol.session import LinkSession, ProtocolMismatch, sniff_version
from dyno.protocol.vectors import VECTOR_DIR
from dyno.sim.device import EmulatedFirmware

from .test_protocol_vectors import _events

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def _lines(name):
    for line in (VECTOR_DIR / name).read_text().splitlines():
        if line and not line.startswith("#"):
            kind, *rest = line.split()
            yield kind, rest, dict(f.split("=", 1) for f in rest if "=" in f)


def test_crc32c_check_value_and_vectors():
    assert crc32c(b"123456789") == 0xE3069283
    n = 0
    for kind, rest, _ in _lines("v2.hex"):
        if kind == "crc32c":
            data = b"" if rest[0] == "-" else bytes.fromhex(rest[0])
            assert crc32c(data) == int(rest[1], 16)
            n += 1
    assert n == 4


def test_v2_vectors_decode_to_their_fields():
    seen = {"frame": 0, "info": 0, "bad": 0, "cmd": 0, "badcmd": 0}
    for kind, _, f in _lines("v2.hex"):
        raw = bytes.fromhex(f.get("hex", ""))
        if kind == "frame":
            fr = v2.decode_frame(raw)
            assert (fr.seq, fr.flags, fr.boot_id, fr.events_dropped, fr.t0_us) == tuple(
                int(f[k]) for k in ("seq", "flags", "boot", "dropped", "t0"))
            assert fr.events == _events(f["events"])
            assert v2.encode_data_frame(fr.seq, fr.flags, fr.boot_id, fr.events_dropped, fr.events,
                                        fr.t0_us) == raw
        elif kind == "info":
            fr = v2.decode_frame(raw)
            assert isinstance(fr, v2.InfoFrame)
            assert fr.boot_id == int(f["boot"]) and fr.reset_cause == v2.CAUSE_WDRF
            assert fr.lockout_rejected == (11, 22) and fr.glitch_rejected == (333, 4444)
            assert (fr.twi_timeouts, fr.bus_errors) == (5, 250)
        elif kind == "bad":
            with pytest.raises(FrameError) as exc:
                v2.decode_frame(raw)
            assert exc.value.cause == f["cause"]
        elif kind == "cmd":
            cmd = v2.decode_command(raw)
            args = () if f["args"] == "-" else tuple(map(int, f["args"].split(",")))
            assert (cmd.op, cmd.args) == (int(f["op"]), args)
        elif kind == "badcmd":
            with pytest.raises(FrameError) as exc:
                v2.decode_command(raw)
            assert exc.value.cause == f["cause"]
        if kind in seen:
            seen[kind] += 1
    assert seen["frame"] >= 10 and seen["info"] == 1 and seen["bad"] >= 10 and seen["cmd"] == 6


def test_v2_frames_fit_the_wire_buffer():
    events = [v1.Event(3, 1000 * i, 1, 2) for i in range(10)]
    n = v2.fit_events(events)
    assert n == 2  # two 6-byte ADC events in 15 bytes
    assert v2.encode_data_frame(0, 0, 1, 0, events[:n])[1] <= 32
    with pytest.raises(ValueError):
        v2.encode_data_frame(0, 0, 1, 0, events[: n + 1])
    assert v2.fit_events([v1.Event(1, i) for i in range(9)]) == 5


def _xfer(s, fw, now, corrupt_read=False):
    fw.write(s.request(), now)
    raw = fw.read(32, now)
    if corrupt_read:
        raw = raw[:14] + bytes([raw[14] ^ 0x10]) + raw[15:]
    return s.accept(raw)


def test_reset_right_after_the_first_frame_is_seen_at_the_new_boots_first_frame():
    fw = EmulatedFirmware()
    s = LinkSession()
    fw.capture("primary", 0.001)
    f = _xfer(s, fw, 0.002)
    assert f is not None and f.seq == 0 and f.boot_id == 1 and f.reset_cause == v2.CAUSE_PORF
    fw.reset(0.003)  # watchdog, right after the first frame went out
    fw.capture("primary", 0.004)
    f = _xfer(s, fw, 0.005)  # the very next read is the new boot's first frame
    assert f is not None and s.new_boot and s.stats.device_resets == 1
    assert f.boot_id == 2 and f.reset_cause == v2.CAUSE_WDRF
    assert [b["cause_name"] for b in s.stats.boots] == ["power-on", "watchdog"]


def test_no_ack_from_an_old_boot_retires_a_frame_of_the_new_one():
    """Host accepted old seq 0; the device reboots; the new seq 0 is sent but its read is corrupted.
    v1 would retire it with the host's ACK_POLL(0) and lose its events uncounted; v2 must not."""
    for version in (2, 1):
        fw = EmulatedFirmware(f"v{version}")
        s = LinkSession(version)
        got = []
        f = _xfer(s, fw, 0.001)
        assert f is not None and f.seq == 0
        fw.reset(0.002)
        fw.capture("secondary", 0.0025)
        assert _xfer(s, fw, 0.003, corrupt_read=True) is None  # new seq 0 sent, lost on the wire
        for k in range(5):
            f = _xfer(s, fw, 0.004 + k * 0.001)
            if f is not None:
                got.extend(f.events)
        if version == 2:
            assert len(got) == 1 and s.stats.device_resets == 1 and fw.ack_from_old_boot >= 1
        else:  # the v1 defect this version fixes: the event is gone and the reset unseen
            assert got == [] and s.stats.device_resets == 0


def test_random_resets_every_one_seen_with_its_cause():
    rng = random.Random(3)
    fw = EmulatedFirmware()
    s = LinkSession()
    t, resets, clean_read_boots, causes = 0.0, 0, set(), {1: v2.CAUSE_PORF}
    for i in range(4000):
        t += 1 / 150
        for _ in range(rng.randint(0, 3)):
            t += 0.0005
            fw.capture(rng.choice(["primary", "secondary", "adc"]), t)
        if rng.random() < 0.01:
            cause = rng.choice([v2.CAUSE_WDRF, v2.CAUSE_EXTRF, v2.CAUSE_BORF])
            fw.reset(t, cause=cause)
            causes[fw.boot_id] = cause
            resets += 1
        corrupt = rng.random() < 0.1
        if not corrupt:
            clean_read_boots.add(fw.boot_id)
        _xfer(s, fw, t, corrupt_read=corrupt)
    assert resets > 20
    seen = {b["boot_id"]: b["cause"] for b in s.stats.boots}
    assert clean_read_boots <= set(seen)  # a boot with one good read is always seen...
    assert all(seen[b] == causes[b] for b in seen)  # ...with its cause
    assert s.stats.device_resets == len(s.stats.boots) - 1
    assert fw.ack_from_old_boot > 0  # stale acknowledgements happened and were refused


def test_version_mismatch_is_refused_naming_both_versions():
    fw1 = EmulatedFirmware("v1")
    raw1 = fw1.read(32, 0.0)
    assert sniff_version(raw1) == "v1"
    s = LinkSession(2)
    assert s.accept(raw1) is None and s.stats.rejected["version"] == 1  # once could be noise
    with pytest.raises(ProtocolMismatch) as exc:
        s.accept(raw1)  # twice in a row is a v1 device
    msg = str(exc.value)
    assert "v1" in msg and "v2" in msg and "\n" not in msg
    assert isinstance(exc.value, ConfigError)
    raw2 = EmulatedFirmware("v2").read(32, 0.0)
    s = LinkSession(1)
    s.accept(raw2)
    with pytest.raises(ProtocolMismatch, match="speaks protocol v2, the host is set to v1"):
        s.accept(raw2)
    # v0 sketch on a v2 host (20 bytes, then 0xFF: SDA released), and a v2 device read as v0
    raw0 = EmulatedFirmware("v0").read(32, 0.0)
    s = LinkSession(2)
    s.accept(raw0)
    with pytest.raises(ProtocolMismatch, match="speaks protocol v0, the host is set to v2"):
        s.accept(raw0)

    class T:
        def transfer(self, request, n):
            return raw2[:n]
    r0 = make_reader("v0", T())
    assert r0.poll(0.0) == []
    with pytest.raises(ProtocolMismatch, match="speaks protocol v2, the host is set to v0"):
        r0.poll(0.0)
    # corruption is not a mismatch: a bad CRC of the right version is counted, not refused
    bad = bytearray(raw2)
    bad[0] = 1
    s = LinkSession(2)
    assert s.accept(bytes(bad)) is None and s.stats.rejected["version"] == 1
    assert v0.FRAME_LEN == 20


def test_info_frame_from_the_emulated_device():
    fw = EmulatedFirmware()
    fw.capture("primary", 0.001)
    fw.capture("primary", 0.0015)  # inside the 1 ms lock-out floor: rejected and counted
    fw.write(v2.encode_command(v2.OP_INFO), 0.5)
    info = v2.decode_frame(fw.read(32, 0.5))
    assert isinstance(info, v2.InfoFrame)
    assert info.boot_id == 1 and info.reset_cause == v2.CAUSE_PORF and info.uptime_ms == 500
    assert info.lockout_rejected == (1, 0)


def test_gap_mark_after_ring_saturation_and_rpm_by_pairs():
    from dyno.acquisition.rpm import rpm_by_pairs
    from dyno.acquisition.streams import Streams

    fw = EmulatedFirmware(ring_capacity=4)
    for k in range(10):  # 10 edges 10 ms apart into a 4-event ring: 6 dropped
        fw.capture("primary", 0.01 * (k + 1))
    s = LinkSession()
    got = []
    for k in range(12):
        f = _xfer(s, fw, 0.2 + 0.01 * k)
        if f:
            got.extend(f.events)
        if k == 1:  # room again: the next edge carries the gap mark
            fw.capture("primary", 0.11)
            fw.capture("primary", 0.12)
    assert [e.gap for e in got] == [False, False, False, False, True, False]
    st = Streams()
    st.extend(got)
    assert list(st.edge_gap[v1.CH_PRIMARY]) == [0, 0, 0, 0, 1, 0]
    rpm, n = rpm_by_pairs(st.edges[v1.CH_PRIMARY], st.edge_gap[v1.CH_PRIMARY])
    assert n == 4 and rpm == pytest.approx(6000.0, rel=1e-3)  # 10 ms periods only


def test_poller_rpm_never_spans_a_gap():
    """Live speed: if events were lost between the last two edges, the latest period without a
    loss is used (never the long one across the hole); a channel gone quiet still reads 0."""
    from dyno.acquisition.poller import Poller

    class Reader:
        device_time_us = 0

    p = Poller(Reader())
    evs = [v1.Event(1, 10_000 * k) for k in range(1, 6)]  # 10 ms periods: 6000 rpm
    evs.append(v1.Event(3, 55_000, 1, 0, gap=True))  # ring saturated: edges lost here
    evs.append(v1.Event(1, 90_000))  # 40 ms after the last edge we got
    p.streams.extend(evs)
    p.reader.device_time_us = 91_000
    assert list(p.streams.edge_gap[v1.CH_PRIMARY]) == [0, 0, 0, 0, 0, 1]
    assert p.rpm(v1.CH_PRIMARY) == pytest.approx(6000.0)  # not 60e6 / 40 ms = 1500
    p.reader.device_time_us = 90_000 + 600_000
    assert p.rpm(v1.CH_PRIMARY) == 0.0  # quiet for 0.6 s
    p.streams.extend([v1.Event(1, 700_000), v1.Event(1, 710_000)])
    p.reader.device_time_us = 711_000
    assert p.rpm(v1.CH_PRIMARY) == pytest.approx(6000.0)
