import pytest
"""Acknowledge/re-send, stale repeats, resets, and the unwrapping of device time."""

import random

from dyno.acquisition.reader import Unwrapper
from dyno.protocol import v1, v2
from dyno.protocol.session import LinkSession
from dyno.sim.device import EmulatedFirmware

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def _exchange(session, fw, now, corrupt=None):
    req = session.request()
    if corrupt == "write":
        req = bytes([req[0] ^ 0x01]) + req[1:]
    fw.write(req, now)
    raw = fw.read(32, now)
    if corrupt == "read":
        raw = bytes([raw[0]]) + bytes([raw[1]]) + bytes([raw[2] ^ 0x40]) + raw[3:]
    return session.accept(raw)


def test_every_event_arrives_once_despite_corrupted_reads_and_acks():
    rng = random.Random(5)
    fw = EmulatedFirmware()
    s = LinkSession()
    sent, got = [], []
    t = 0.0
    for i in range(3000):
        t += 1 / 150
        for _ in range(rng.randint(0, 4)):
            ch = rng.choice(["primary", "secondary", "adc"])
            t += 0.0007
            before = fw.events_generated
            fw.capture(ch, t, code=rng.randrange(65536), status=rng.choice([0, 5, 0x25]))
            if fw.events_generated > before:
                sent.append(fw.ring[-1])
        corrupt = rng.choice([None] * 6 + ["write", "read"])
        frame = _exchange(s, fw, t, corrupt)
        if frame:
            got.extend(frame.events)
    for _ in range(200):  # drain
        t += 1 / 150
        frame = _exchange(s, fw, t)
        if frame:
            got.extend(frame.events)
    assert got == sent
    assert s.stats.rejected["stale_repeat"] > 0  # lost acknowledgements happened and were caught
    assert s.stats.rejected["crc"] > 0


def test_device_reset_is_seen_and_accepted():
    fw = EmulatedFirmware()
    s = LinkSession()
    for k in range(5):
        fw.capture("primary", 0.02 * k)
        _exchange(s, fw, 0.02 * k + 0.001)
    fw.reset(1.0)
    fw.capture("primary", 1.01)
    frame = _exchange(s, fw, 1.02)
    assert frame is not None and frame.flags & v1.FLAG_RESET
    assert s.stats.device_resets == 1


def test_first_frame_after_reset_is_not_retired_by_a_stale_ack():
    for proto, ack in ((v1, v1.poll(0)), (v2, v2.poll((1, 0)))):
        fw = EmulatedFirmware(f"v{proto.VERSION}")
        fw.capture("primary", 0.001)
        fw.write(ack, 0.002)  # ack 0 before frame 0 was ever sent
        raw = fw.read(32, 0.003)
        assert proto.decode_frame(raw).events  # still there


def test_unwrap_crosses_2_32():
    u = Unwrapper()
    times = [(0xFFFFFF00 + 1000 * i) & 0xFFFFFFFF for i in range(10)]
    out = [u(t) for t in times]
    assert out == [0xFFFFFF00 + 1000 * i for i in range(10)]


def test_unwrap_tolerates_small_reordering():
    u = Unwrapper()
    assert [u(t) for t in (100, 50, 200)] == [100, 50, 200]
