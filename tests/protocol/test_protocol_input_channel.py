"""The engine-side input torque channel (issue 27): tag 4, CAPS / SET_CHANNELS, and who sees what.

Old hosts never see tag 4 (the device queues it only after SET_CHANNELS in this boot), old firmware
never announces it (CAPS is an unknown op there: the host finds the channel absent, loses nothing).
"""

import random

import pytest

from dyno.acquisition.reader import CAPS_TRIES, V1Reader
from dyno.errors import FrameError
from dyno.protocol import v1, v2
from dyno.protocol.session import LinkSession
from dyno.protocol.vectors import VECTOR_DIR
from dyno.sim.device import EmulatedFirmware
from dyno.transports.base import Transport, TransportFault

from .test_protocol_vectors import _events

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def _lines(name):
    for line in (VECTOR_DIR / name).read_text().splitlines():
        if line and not line.startswith("#"):
            kind, *rest = line.split()
            yield kind, dict(f.split("=", 1) for f in rest if "=" in f)


def test_input_vectors_decode_and_reencode():
    seen = {"frame": 0, "caps": 0, "cmd": 0}
    for kind, f in _lines("v2-input.hex"):
        raw = bytes.fromhex(f["hex"])
        seen[kind] += 1
        if kind == "frame":
            fr = v2.decode_frame(raw)
            assert fr.events == _events(f["events"])
            assert v2.encode_data_frame(fr.seq, fr.flags, fr.boot_id, fr.events_dropped, fr.events, fr.t0_us) == raw
        elif kind == "caps":
            fr = v2.decode_frame(raw)
            assert isinstance(fr, v2.CapsFrame)
            assert (fr.seq, fr.flags, fr.boot_id, fr.channels, fr.enabled, fr.input_converter, fr.input_rate_mhz) \
                == tuple(int(f[k]) for k in ("seq", "flags", "boot", "channels", "enabled", "converter", "rate_mhz"))
            assert v2.encode_caps_frame(fr) == raw
        else:
            cmd = v2.decode_command(raw)
            assert cmd.op == int(f["op"])
    assert seen == {"frame": 4, "caps": 3, "cmd": 3}
    # the input conversion keeps its code and status bits (the error bit the safety monitor watches)
    fr = v2.decode_frame(bytes.fromhex(dict(_lines("v2-input.hex").__iter__().__next__()[1])["hex"]))
    assert fr.events[0].channel == v2.CH_INPUT and fr.events[0].code == 36000 and fr.events[0].status == 5


def test_a_v1_decoder_rejects_tag_4_and_caps_is_unknown_to_it():
    """Why the host must ask first: a decoder without the extension refuses tag 4 as a bad tag."""
    frame = v1.encode_data_frame(1, 0, 0, [v1.Event(1, 10)])
    bad = bytearray(frame)
    bad[11] = 4
    with pytest.raises(FrameError):
        v1.decode_frame(bytes(bad))
    with pytest.raises(FrameError) as exc:
        v1.decode_command(v2.encode_command(v2.OP_CAPS))
    assert exc.value.cause == "op"


def test_caps_frame_structure_is_checked():
    raw = bytearray(v2.encode_caps_frame(v2.CapsFrame(0, 0, 1, 1, 0, 1, 125000)))
    raw[14] = 1  # a reserved byte, then a valid CRC over it
    from dyno.protocol.crc import crc32c
    raw[16:20] = crc32c(bytes(raw[:16])).to_bytes(4, "big")
    with pytest.raises(FrameError) as exc:
        v2.decode_frame(bytes(raw))
    assert exc.value.cause == "padding"


class DeviceTransport(Transport):
    """The emulated firmware on a bus; ``corrupt`` loses a fraction of transfers (not the device's fault)."""

    def __init__(self, fw, corrupt: float = 0.0, seed: int = 0):
        super().__init__()
        self.fw, self.now, self.corrupt = fw, 0.0, corrupt
        self.rng = random.Random(seed)

    def _transfer(self, request, read_len):
        if self.corrupt and self.rng.random() < self.corrupt:
            raise TransportFault("nack")
        self.fw.write(request, self.now)
        return self.fw.read(read_len, self.now) if read_len else b""


def _run(fw, reader, tr, seconds=1.0, rate_hz=125.0, reset_at=None):
    """Capture both converters and a Hall channel; poll at 150 Hz; returns the host's events."""
    got, t = [], 0.0
    k_adc = 0
    while t < seconds:
        t += 1 / 150
        while (k_adc + 1) / rate_hz <= t:
            k_adc += 1
            ta = k_adc / rate_hz
            fw.capture("adc", ta, 35000 + k_adc, 5)
            fw.capture("input", ta + 0.0011, 30000 + k_adc, 5)
            fw.capture("primary", ta + 0.0021)
        if reset_at is not None and t >= reset_at:
            fw.reset(t)
            reset_at = None
        tr.now = t
        for _ in range(8):
            got.extend(reader.poll(t))
            if not reader.more:
                break
    return got


@pytest.mark.parametrize("corrupt", [0.0, 0.05])
def test_new_host_new_firmware_enables_the_channel_losslessly_and_again_after_a_reset(corrupt):
    fw = EmulatedFirmware(input_fitted=True)
    tr = DeviceTransport(fw, corrupt, seed=4)
    reader = V1Reader(tr)
    reader.want_input = True
    got = _run(fw, reader, tr, seconds=2.0, reset_at=1.0)
    assert reader.input_present is True and fw.channels_enabled == v2.CHANNEL_INPUT
    inputs = [e for e in got if e.channel == v2.CH_INPUT]
    adcs = [e for e in got if e.channel == v1.CH_ADC]
    # every input conversion the device queued reached the host (none dropped, none twice)
    assert reader.events_lost == 0 and fw.events_dropped == 0
    assert len({e.code for e in inputs}) == len(inputs)
    # both boots carried the channel: conversions shortly after the reset arrived (re-enabled)
    codes = sorted(e.code for e in inputs)
    assert codes[0] - 30000 < 10 and codes[-1] - 30000 > 240
    after_reset = [c for c in codes if c - 30000 > 125]
    assert after_reset and after_reset[0] - 30000 < 125 + 15
    assert len(inputs) > 0.85 * len(adcs)


def test_old_host_never_receives_tag_4():
    """A host that does not ask (an old host, or a rig file without the channel) reads exactly as before."""
    fw = EmulatedFirmware(input_fitted=True)
    tr = DeviceTransport(fw)
    s = LinkSession(2)
    for k in range(200):
        fw.capture("adc", k * 0.008, 1000 + k, 5)
        fw.capture("input", k * 0.008 + 0.001, 2000 + k, 5)
        tr.now = k * 0.008 + 0.002
        buf = tr.transfer(s.request(), 32)
        assert buf[2] == v1.KIND_DATA
        assert b"\x04" not in bytes(buf[13:buf[1] - 4:6])  # no tag 4 (ADC events start every 6 bytes here)
        s.accept(buf)
    assert s.stats.rejected.get("event_tag", 0) == 0 and s.stats.accepted >= 150


def test_old_firmware_found_without_the_channel_nothing_lost():
    fw = EmulatedFirmware(input_fitted=True, knows_caps=False)
    tr = DeviceTransport(fw)
    reader = V1Reader(tr)
    reader.want_input = True
    got = _run(fw, reader, tr, seconds=0.5)
    assert reader.input_present is False
    assert not [e for e in got if e.channel == v2.CH_INPUT]
    adc_codes = [e.code for e in got if e.channel == v1.CH_ADC]
    assert adc_codes == list(range(35001, 35001 + len(adc_codes))) and len(adc_codes) >= 60
    assert tr.transfers < reader.stats.read + CAPS_TRIES + 2  # it stopped asking


def test_firmware_without_the_converter_announces_none():
    fw = EmulatedFirmware(input_fitted=False)
    tr = DeviceTransport(fw)
    reader = V1Reader(tr)
    reader.want_input = True
    got = _run(fw, reader, tr, seconds=0.3)
    assert reader.input_present is False and fw.channels_enabled == 0
    assert reader.session.caps is not None and not reader.session.caps.has_input
    assert not [e for e in got if e.channel == v2.CH_INPUT]
