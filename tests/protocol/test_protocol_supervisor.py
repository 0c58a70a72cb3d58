"""The run-enable supervisor's wire contract (issue 37): flag RUN, tag 5, SET_SUPERVISOR, the capability bit.

The vectors bind the host's codec to the firmware's (``firmware/test/native`` reads the same file).
"""

import pytest

from dyno.errors import FrameError
from dyno.protocol import v2

from .test_protocol_input_channel import _lines
from .test_protocol_vectors import _events

pytestmark = pytest.mark.quick


def test_supervisor_vectors_decode_and_reencode():
    seen = {"frame": 0, "caps": 0, "cmd": 0, "info": 0, "badcmd": 0}
    for kind, f in _lines("v2-supervisor.hex"):
        raw = bytes.fromhex(f["hex"])
        seen[kind] += 1
        if kind == "frame":
            fr = v2.decode_frame(raw)
            assert fr.events == _events(f["events"]) and fr.flags == int(f["flags"])
            assert v2.encode_data_frame(fr.seq, fr.flags, fr.boot_id, fr.events_dropped, fr.events, fr.t0_us) == raw
        elif kind == "caps":
            fr = v2.decode_frame(raw)
            assert fr.has_supervisor and fr.channels == int(f["channels"]) and fr.enabled == int(f["enabled"])
            assert v2.encode_caps_frame(fr) == raw
        elif kind == "info":
            fr = v2.decode_frame(raw)
            assert fr.flags & v2.FLAG_RUN and fr.fw_version == (2, 1, 0)
            assert v2.encode_info_frame(fr) == raw
        elif kind == "cmd":
            cmd = v2.decode_command(raw)
            assert cmd.op == int(f["op"]) in (v2.OP_SET_SUPERVISOR, v2.OP_PULSE_RUN_ENABLE)
            assert cmd.args == tuple(int(a) for a in f["args"].split(","))
        else:
            with pytest.raises(FrameError) as e:
                v2.decode_command(raw)
            assert e.value.cause == f["cause"]
    assert seen == {"frame": 7, "caps": 3, "cmd": 5, "info": 1, "badcmd": 3}


def test_supervisor_event_carries_cause_and_measured_value():
    fr = v2.decode_frame(bytes.fromhex(dict(_lines("v2-supervisor.hex"))["frame"]["hex"]))  # (the last frame line)
    assert isinstance(fr, v2.DataFrame)
    for kind, f in _lines("v2-supervisor.hex"):
        if kind == "frame" and f["events"].startswith("1@4000000"):
            ev = v2.decode_frame(bytes.fromhex(f["hex"])).events[-1]
            assert ev.channel == v2.CH_SUPERVISOR and ev.status == v2.SUP_OVERSPEED_PRIMARY and ev.code == 13000
            assert v2.SUP_CAUSE_NAMES[ev.status] == "overspeed_primary"


def test_pulse_command_and_its_events():
    """PULSE_RUN_ENABLE (issue 49): u16 ms, CRC-16 like every command; its drop is a PULSE event (code = the
    length), its end an ON event; 0 ms and over PULSE_MS_MAX are refused by the host's encoder."""
    raw = v2.pulse_command(100)
    assert raw[:3] == bytes([0x24, 0x00, 0x64]) and len(raw) == 5
    assert v2.decode_command(raw).args == (100,)
    assert v2.decode_command(v2.pulse_command(v2.PULSE_LATCH)).args == (0xFFFF,)
    for bad in (0, v2.PULSE_MS_MAX + 1, v2.PULSE_LATCH - 1):
        with pytest.raises(ValueError):
            v2.pulse_command(bad)
    frames = {int(f["seq"]): v2.decode_frame(bytes.fromhex(f["hex"])) for k, f in _lines("v2-supervisor.hex")
              if k == "frame"}
    start, end = frames[13], frames[14]
    assert [(e.channel, e.status, e.code) for e in start.events] == [(5, v2.SUP_PULSE, 100), (1, 0, 0)]
    assert [(e.channel, e.status, e.code) for e in end.events] == [(1, 0, 0), (5, v2.SUP_ON, 0)]
    assert not start.flags & v2.FLAG_RUN and end.flags & v2.FLAG_RUN
    assert end.events[-1].t_us - start.events[0].t_us == 100_000 and v2.SUP_CAUSE_NAMES[v2.SUP_PULSE] == "pulse"


def test_min_period_from_the_rig_limits():
    assert v2.min_period_us(4200.0) == 14285  # 60e6 / 4200 rounded down: a period shorter than this is over
    assert v2.min_period_us(None) == 0 and v2.min_period_us(0) == 0  # not checked
    assert v2.min_period_us(100.0) == 0xFFFF  # saturated
    cmd = v2.decode_command(v2.supervisor_command(4200.0, 7800.0, 0.2))
    assert cmd.args == (14285, 7692, 200)
    assert v2.decode_command(v2.supervisor_command(4200.0, None, 0.0)).args[2] == 1  # never 0 (ignored by the device)


def test_an_old_decoder_refuses_flag_run_so_the_device_sets_it_only_once_armed():
    """Why RUN is set only after the host's SET_SUPERVISOR: a decoder without bit 3 in FLAGS_KNOWN refuses it."""
    raw = bytearray(v2.encode_data_frame(0, v2.FLAG_RUN, 1, 0, []))
    assert v2.decode_frame(bytes(raw)).flags & v2.FLAG_RUN
    old_known = v2.FLAG_RESET | v2.FLAG_MORE | v2.FLAG_OVERFLOW | 0xF0
    assert v2.FLAG_RUN & ~old_known
