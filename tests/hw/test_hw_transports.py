"""Serial COBS framing, the recovering I2C transport, and the MLX90614 PEC."""

from __future__ import annotations

import errno
import random

import pytest
import serial

from dyno.errors import TransportError
from dyno.clock import FakeClock
from dyno.hw.thermometer import MLX90614, ThermometerError, smbus_pec
from dyno.protocol import v1
from dyno.transports.base import TransportFault
from dyno.transports.i2c import RecoveringI2CTransport
from dyno.transports.serial import (CobsDeframer, SerialTransport, cobs_decode, cobs_encode, is_v1_frame)

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def frames(n, seed=1):
    rng = random.Random(seed)
    out = []
    for seq in range(n):
        evs = [v1.Event(rng.choice([1, 2]), 1000 * seq + 10 * k) for k in range(rng.randint(0, 6))]
        out.append(v1.encode_data_frame(seq & 0xFF, 0, 0, evs, now_us=1000 * seq)[: 32])
    return [f[: f[1]] for f in out]  # serial sends L bytes, no padding


# ----------------------------------------------------------------------------- COBS

@pytest.mark.parametrize("data", [b"", b"\x00", b"\x00\x00", b"\x11\x22\x00\x33", bytes(range(256)) * 2,
                                  bytes([1] * 254), bytes([1] * 255), bytes([1] * 253) + b"\x00"])
def test_hw_cobs_round_trip(data):
    enc = cobs_encode(data)
    assert 0 not in enc
    assert cobs_decode(enc) == data


def test_hw_cobs_known_vectors():
    # Wikipedia's examples
    assert cobs_encode(b"\x00") == b"\x01\x01"
    assert cobs_encode(b"\x11\x22\x00\x33") == b"\x03\x11\x22\x02\x33"
    assert cobs_encode(b"\x11\x00\x00\x00") == b"\x02\x11\x01\x01\x01"
    with pytest.raises(ValueError):
        cobs_decode(b"\x05\x11")


def test_hw_deframer_resyncs_after_garbage_and_loses_no_frame():
    rng = random.Random(7)
    fs = frames(300)
    stream = bytearray()
    for f in fs:
        r = rng.random()
        if r < 0.3:  # garbage glued to the front, no delimiter in between
            stream += bytes(rng.randrange(1, 256) for _ in range(rng.randint(1, 40)))
        elif r < 0.45:  # garbage ending in its own delimiter(s)
            stream += bytes(rng.randrange(256) for _ in range(rng.randint(1, 60))) + b"\x00"
        elif r < 0.5:
            stream += b"\x00" * rng.randint(1, 3)  # empty packets
        stream += cobs_encode(f) + b"\x00"
    d = CobsDeframer()
    got = []
    i = 0
    while i < len(stream):  # arbitrary read sizes, like a UART
        n = rng.randint(1, 50)
        got += d.feed(bytes(stream[i:i + n]))
        i += n
    assert got == fs
    assert d.stats["garbage_bytes"] > 0


def test_hw_serial_loop_url_resync():
    port = serial.serial_for_url("loop://", timeout=0.01)
    t = SerialTransport(port, timeout_s=0.2)
    fs = frames(20, seed=3)
    for k, f in enumerate(fs):
        if k % 3 == 0:
            port.write(b"\xde\xad\xbe\xef\x55")  # line noise
        port.write(cobs_encode(f) + b"\x00")
    got = t.receive()
    assert got == fs
    t.close()


class FakePort:
    """Answers each request packet with the next scripted byte string."""

    def __init__(self, answers):
        self.answers = list(answers)
        self.rx = bytearray()
        self.written = []
        self.timeout = 0

    @property
    def in_waiting(self):
        return len(self.rx)

    def write(self, data):
        self.written.append(bytes(data))
        if self.answers:
            self.rx += self.answers.pop(0)

    def read(self, n):
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out


def test_hw_serial_transfer_pads_and_sends_cobs():
    fs = frames(3, seed=5)
    port = FakePort([b"\x42\x42" + cobs_encode(fs[0]) + b"\x00", cobs_encode(fs[1]) + b"\x00", b"junk"])
    t = SerialTransport(port, timeout_s=0.01)
    req = v1.poll(None)
    buf = t.transfer(req, 32)
    assert port.written[0] == cobs_encode(req) + b"\x00"
    assert len(buf) == 32 and buf[: len(fs[0])] == fs[0] and not any(buf[len(fs[0]):])
    assert v1.decode_frame(buf).seq == 0
    assert v1.decode_frame(t.transfer(v1.poll(0), 32)).seq == 1
    with pytest.raises(TransportFault) as exc:
        t.transfer(v1.poll(1), 32)  # only garbage comes back
    assert exc.value.cause == "timeout" and t.failures["timeout"] == 1


def test_hw_is_v1_frame():
    f = frames(1)[0]
    assert is_v1_frame(f)
    assert not is_v1_frame(f[:-1] + bytes([f[-1] ^ 1]))


# ----------------------------------------------------------------------------- I2C

class FlakyBus:
    def __init__(self, errors, payload=b"\x01" * 32):
        self.errors = list(errors)
        self.payload = payload
        self.calls = 0
        self.closed = False

    def i2c_rdwr(self, *msgs):
        self.calls += 1
        if self.errors:
            e = self.errors.pop(0)
            if e:
                raise OSError(e, "injected")
        for m in msgs:
            if m.flags & 1:
                import ctypes

                ctypes.memmove(m.buf, self.payload, m.len)

    def close(self):
        self.closed = True


def test_hw_i2c_retries_with_backoff():
    clock = FakeClock()
    bus = FlakyBus([errno.EREMOTEIO, errno.EREMOTEIO, 0])
    t = RecoveringI2CTransport(bus, 0x03, retries=3, retry_backoff_s=0.002, clock=clock)
    assert t.transfer(b"\x10\x00\x00", 32) == b"\x01" * 32
    assert clock.slept_s == [0.002, 0.004]
    assert t.retried["nack"] == 2 and not t.failures


def test_hw_i2c_recovers_stuck_bus_and_resets_arduino():
    clock = FakeClock()
    buses = []
    resets = []

    def reopen():
        b = FlakyBus([errno.ETIMEDOUT] * 100)
        buses.append(b)
        return b

    first = FlakyBus([errno.ETIMEDOUT] * 100)
    t = RecoveringI2CTransport(first, 0x03, retries=1, reset_after_failures=3, reopen=reopen,
                               reset=lambda: resets.append(clock.now()), clock=clock)
    for k in range(3):
        with pytest.raises(TransportError) as exc:
            t.transfer(b"\x10", 32)
        assert exc.value.cause == "timeout"
    assert first.closed and t.recoveries == 6
    assert len(resets) == 1 and t.resets == 1 and t.failures["timeout"] == 3


# ----------------------------------------------------------------------------- MLX90614

class ThermoBus:
    def __init__(self, temp_c=85.0, corrupt_pec=False, error_flag=False, address=0x5A):
        self.raw = round((temp_c + 273.15) / 0.02) | (0x8000 if error_flag else 0)
        self.corrupt = corrupt_pec
        self.address = address
        self.seen = []

    def i2c_rdwr(self, *msgs):
        import ctypes

        assert len(msgs) == 2  # one combined transaction: write cmd, repeated start, read 3
        wr, rd = msgs
        cmd = bytes(wr)[0]
        self.seen.append((wr.addr, cmd, rd.len))
        a = self.address << 1
        lsb, msb = self.raw & 0xFF, self.raw >> 8
        pec = smbus_pec(bytes([a, cmd, a | 1, lsb, msb])) ^ (0x01 if self.corrupt else 0)
        ctypes.memmove(rd.buf, bytes([lsb, msb, pec]), 3)


def test_hw_smbus_pec_known_value():
    # CRC-8/SMBUS check value: "123456789" -> 0xF4
    assert smbus_pec(b"123456789") == 0xF4


def test_hw_mlx90614_reads_object_temperature():
    bus = ThermoBus(85.0)
    t = MLX90614(bus)
    assert t.object_c() == pytest.approx(85.0, abs=0.02)
    assert bus.seen == [(0x5A, 0x07, 3)]


def test_hw_mlx90614_bad_pec_is_an_error():
    t = MLX90614(ThermoBus(85.0, corrupt_pec=True))
    with pytest.raises(ThermometerError) as exc:
        t.object_c()
    assert exc.value.cause == "pec" and t.errors == {"pec": 1}


def test_hw_mlx90614_error_flag():
    with pytest.raises(ThermometerError) as exc:
        MLX90614(ThermoBus(20.0, error_flag=True)).object_c()
    assert exc.value.cause == "error_flag"


def test_hw_mlx90614_nack():
    class Dead:
        def i2c_rdwr(self, *m):
            raise OSError(errno.EREMOTEIO, "nack")

    with pytest.raises(ThermometerError) as exc:
        MLX90614(Dead()).object_c()
    assert exc.value.cause == "nack"


def test_hw_serial_deframer_takes_v2_frames_after_garbage():
    from dyno.protocol import v2
    from dyno.transports.serial import is_frame, is_v2_frame

    frames = [v2.encode_data_frame(k, 0x10, 7, 0, [v1.Event(1, 1000 * k)], 0)[:20] for k in range(5)]
    assert all(is_v2_frame(f) and is_frame(f) for f in frames)
    assert not is_v1_frame(frames[0])
    bad = bytearray(frames[0])
    bad[-1] ^= 1
    assert not is_frame(bytes(bad))
    d = CobsDeframer()
    stream = b"\x13\x37garbage" + b"".join(cobs_encode(f) + b"\0" for f in frames)
    assert d.feed(stream) == frames


class EchoBus:
    """Answers each read with the request it got (padded), slowly enough that two threads overlap; a
    ``short`` read fills only its first bytes, as a read cut short leaves the rest of the buffer alone."""

    def __init__(self, short: int | None = None) -> None:
        self.short = short

    def i2c_rdwr(self, *msgs) -> None:
        import ctypes
        import time

        req = bytes(msgs[0])
        time.sleep(0.0002)
        rd = msgs[-1]
        n = rd.len if self.short is None else self.short
        ctypes.memmove(rd.buf, (req * rd.len)[:n], n)


def test_hw_i2c_reused_messages_never_mix_threads_or_keep_old_bytes():
    import threading

    from dyno.transports.base import I2CTransport

    t = I2CTransport(EchoBus(), 0x03)
    bad: list = []

    def worker(tag: bytes) -> None:
        for i in range(300):
            req = tag + bytes([i % 256])
            out = t.transfer(req, 8)
            if out != (req * 8)[:8]:
                bad.append((req, out))

    threads = [threading.Thread(target=worker, args=(bytes([k]),)) for k in (0xA1, 0xB2, 0xC3)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not bad, bad[:3]
    assert t.transfer(b"\x01\x02", 6) == b"\x01\x02\x01\x02\x01\x02"
    t.bus = EchoBus(short=2)  # the same cached read buffer, a short read: zeros after it, not the last frame
    assert t.transfer(b"\x07\x08", 6) == b"\x07\x08\x00\x00\x00\x00"
