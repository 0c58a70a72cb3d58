"""The golden vectors in the repository: generated, decoded, and agreeing."""

import pytest

from dyno.errors import FrameError
from dyno.protocol import v0, v1
from dyno.protocol.crc import crc16
from dyno.protocol.vectors import VECTOR_DIR, render

pytestmark = pytest.mark.quick  # the inner loop: python -m pytest -m quick -n 2


def _lines(name):
    for line in (VECTOR_DIR / name).read_text().splitlines():
        if line and not line.startswith("#"):
            kind, *rest = line.split()
            fields = dict(f.split("=", 1) for f in rest if "=" in f)
            yield kind, rest, fields


def test_vector_files_match_the_generator():
    for name, text in render().items():
        assert (VECTOR_DIR / name).read_text() == text, f"{name} is stale: run python -m dyno.protocol.vectors"


def test_crc_check_values():
    assert crc16(b"123456789") == 0x29B1
    for kind, rest, _ in _lines("v1.hex"):
        if kind == "crc":
            data = b"" if rest[0] == "-" else bytes.fromhex(rest[0])
            assert crc16(data) == int(rest[1], 16)


def _events(spec):
    if spec == "-":
        return ()
    out = []
    for tok in spec.split(","):
        ch, rest = tok.split("@")
        tag, gap = int(ch) & 0x7F, bool(int(ch) & 0x80)  # v2: bit 7 marks a gap before the event
        if ":" in rest:
            t, code, status = map(int, rest.split(":"))
            out.append(v1.Event(tag, t, code, status, gap))
        else:
            out.append(v1.Event(tag, int(rest), gap=gap))
    return tuple(out)


def test_v1_frames_decode_to_their_fields():
    n = 0
    for kind, _, f in _lines("v1.hex"):
        raw = bytes.fromhex(f.get("hex", ""))
        if kind == "frame":
            fr = v1.decode_frame(raw)
            assert (fr.seq, fr.flags, fr.events_dropped, fr.t0_us) == (
                int(f["seq"]), int(f["flags"]), int(f["dropped"]), int(f["t0"]))
            assert fr.events == _events(f["events"])
            n += 1
        elif kind == "info":
            fr = v1.decode_frame(raw)
            assert isinstance(fr, v1.InfoFrame)
            assert fr.fw_version == tuple(map(int, f["fw"].split(".")))
            assert (fr.boot_count, fr.uptime_ms) == (int(f["boots"]), int(f["uptime_ms"]))
        elif kind == "bad":
            with pytest.raises(FrameError) as exc:
                v1.decode_frame(raw)
            assert exc.value.cause == f["cause"]
        elif kind == "cmd":
            cmd = v1.decode_command(raw)
            args = () if f["args"] == "-" else tuple(map(int, f["args"].split(",")))
            assert (cmd.op, cmd.args) == (int(f["op"]), args)
        elif kind == "badcmd":
            with pytest.raises(FrameError) as exc:
                v1.decode_command(raw)
            assert exc.value.cause == f["cause"]
    assert n >= 8


def test_v0_frames():
    for kind, _, f in _lines("v0.hex"):
        raw = bytes.fromhex(f["hex"])
        if kind == "v0":
            fr = v0.decode_legacy_frame(raw)
            assert (fr.rpm_primary, fr.t_primary_us, fr.rpm_secondary, fr.t_secondary_us, fr.adc_code,
                    fr.t_adc_us) == tuple(int(f[k]) for k in ("rp", "tp", "rs", "ts", "adc", "ta"))
        else:
            with pytest.raises(FrameError) as exc:
                v0.decode_legacy_frame(raw)
            assert exc.value.cause == f["cause"]


def test_frames_never_exceed_the_wire_buffer():
    events = [v1.Event(3, 1000 * i, 1, 2) for i in range(10)]
    n = v1.fit_events(events)
    raw = v1.encode_data_frame(0, 0, 0, events[:n])
    assert len(raw) == 32 and raw[1] <= 32
    with pytest.raises(ValueError):
        v1.encode_data_frame(0, 0, 0, events[: n + 1])


def test_fit_events_respects_the_signed_16_bit_offset():
    events = [v1.Event(1, 0), v1.Event(2, 32767), v1.Event(1, 32768)]
    assert v1.fit_events(events) == 2
