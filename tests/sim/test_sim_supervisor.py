"""The Nano's run-enable, emulated (dyno.sim.device + dyno.sim.supervisor) and read by the host (issue 37).

The emulation must do what the firmware does (the frame-for-frame comparison with the real firmware is in
tests/firmware/test_firmware_supervisor_emulation.py); here its rules, one at a time, against the contract.
"""

import pytest

from dyno.acquisition.reader import make_reader
from dyno.protocol import v1, v2
from dyno.sim.device import EmulatedFirmware
from dyno.transports.base import Transport

pytestmark = pytest.mark.quick

LIMITS = v2.supervisor_command(4200.0, 7800.0, 0.2)


def _drain(fw, now_s):
    """Read and acknowledge every frame queued: the decoded frames."""
    out = []
    for _ in range(100):
        fr = v2.decode_frame(fw.read(32, now_s))
        out.append(fr)
        fw.write(v2.poll((fr.boot_id, fr.seq)), now_s)
        if not fr.events and not fr.flags & v2.FLAG_MORE:
            break
    return out


def _sup_events(frames):
    return [(e.status, e.code) for f in frames for e in f.events if e.channel == v2.CH_SUPERVISOR]


def _edges(fw, channel, rpm, t0_s, t1_s):
    t, period = t0_s, 60.0 / rpm
    while t < t1_s:
        fw.capture(channel, t)
        t += period


def test_boot_off_until_the_limits_then_on_then_heartbeat_drop_latched():
    fw = EmulatedFirmware()
    changes = []
    fw.on_run_enable = lambda on, t, cause: changes.append((on, round(t, 6), cause))
    fw.write(v2.poll(), 0.01)
    assert not fw.run_enable and not _drain(fw, 0.02)[0].flags & v2.FLAG_RUN  # boot: off, no limits
    fw.write(LIMITS, 0.05)
    assert fw.run_enable and changes == [(True, 0.05, "on")]
    frames = _drain(fw, 0.06)
    assert frames[0].flags & v2.FLAG_RUN and _sup_events(frames) == [(v2.SUP_ON, 0)]
    fw.write(v2.poll(), 0.10)  # the last heartbeat
    fw.service(0.2999)
    assert fw.run_enable
    fw.service(0.5)  # found late: the drop is dated when the timeout expired, as the firmware's loop dates it
    assert not fw.run_enable and changes[-1] == (False, 0.3, "heartbeat")
    frames = _drain(fw, 0.51)
    assert _sup_events(frames) == [(v2.SUP_HEARTBEAT, 200)] and not frames[0].flags & v2.FLAG_RUN
    fw.write(v2.poll(), 0.52)  # polls again: still off (latched until the next SET_SUPERVISOR)
    assert not fw.run_enable
    fw.write(LIMITS, 0.6)
    assert fw.run_enable and changes[-1] == (True, 0.6, "on")


def test_overspeed_from_a_period_measured_after_arming():
    fw = EmulatedFirmware()
    _edges(fw, "primary", 4600.0, 0.0, 0.2)  # fast before arming: does not count
    fw.write(LIMITS, 0.2)
    assert fw.run_enable
    t_first = 0.2 + 60.0 / 4600.0
    for k in range(3):  # heartbeats go on: only the speed can drop it
        fw.write(v2.poll(), 0.2 + 0.005 * k)
    _edges(fw, "primary", 4600.0, t_first, t_first + 0.05)
    assert not fw.run_enable
    t_off, on, cause = fw.run_enable_log[-1]
    # the first period wholly after arming ends at the second edge after it: off at that edge
    assert cause == "overspeed_primary" and t_off == pytest.approx(t_first + 60.0 / 4600.0, abs=1e-9)
    (status, code), = [ev for ev in _sup_events(_drain(fw, 0.3)) if ev[0] != v2.SUP_ON]
    assert status == v2.SUP_OVERSPEED_PRIMARY and code == pytest.approx(60e6 / 4600.0, abs=2)


def test_below_the_limit_it_stays_on_while_polled():
    fw = EmulatedFirmware()
    fw.write(LIMITS, 0.0)
    edges = sorted([(k * 60.0 / 3000.0, "primary") for k in range(100)] +
                   [(k * 60.0 / 7000.0, "secondary") for k in range(233)])
    t_poll = 0.0
    for t, ch in edges:
        while t_poll + 0.01 <= t:
            t_poll += 0.01
            fw.write(v2.poll(), t_poll)
        fw.capture(ch, t)
    assert fw.run_enable and [c for _, _, c in fw.run_enable_log] == ["on"]


def test_a_reset_drops_it_and_the_new_boot_waits_for_the_limits():
    fw = EmulatedFirmware()
    fw.write(LIMITS, 0.0)
    fw.write(v2.poll(), 0.1)
    fw.reset(0.15)
    assert not fw.run_enable and fw.run_enable_log[-1] == (0.15, False, "reset")
    caps = None
    fw.write(v2.encode_command(v2.OP_CAPS), 0.2)
    caps = v2.decode_frame(fw.read(32, 0.2))
    assert caps.has_supervisor and not caps.enabled & v2.CHANNEL_SUPERVISOR  # not armed in this boot
    fw.write(LIMITS, 0.25)
    fw.write(v2.encode_command(v2.OP_CAPS), 0.26)
    assert v2.decode_frame(fw.read(32, 0.26)).enabled & v2.CHANNEL_SUPERVISOR


def test_old_firmware_has_no_supervisor_and_ignores_the_command():
    fw = EmulatedFirmware(supervisor=False)
    fw.write(LIMITS, 0.0)
    fw.write(v2.encode_command(v2.OP_CAPS), 0.01)
    caps = v2.decode_frame(fw.read(32, 0.01))
    assert not caps.has_supervisor and not fw.run_enable


def test_supervisor_events_wait_for_room_never_dropped():
    fw = EmulatedFirmware(ring_capacity=8)
    fw.write(LIMITS, 0.0)  # ON is queued (1 of 8)
    _edges(fw, "secondary", 3000.0, 0.001, 0.2)  # the ring fills; the host is silent
    fw.service(0.5)  # heartbeat expires while the ring is full: held
    assert not fw.run_enable and fw._sup_held
    frames = _drain(fw, 0.6)
    assert (v2.SUP_HEARTBEAT, 200) in _sup_events(frames)  # it got in once the host made room


class _EmuTransport(Transport):
    def __init__(self, fw, clock):
        super().__init__()
        self.fw, self.clock = fw, clock

    def _transfer(self, request: bytes, read_len: int) -> bytes:
        self.fw.write(request, self.clock[0])
        return self.fw.read(read_len, self.clock[0]) if read_len else b""


def test_the_host_arms_the_first_boot_only_and_sees_drops_and_their_causes():
    """A new boot while armed stays a cut (issue 49): only the operator's re-arm turns the run-enable on again."""
    fw = EmulatedFirmware()
    clock = [0.0]
    reader = make_reader("v2", _EmuTransport(fw, clock), supervisor_command=LIMITS)
    for k in range(20):
        clock[0] = 0.005 * k
        reader.poll(clock[0])
    assert reader.supervisor_present and reader.supervisor_armed and reader.run_enable and fw.run_enable
    fw.reset(0.2)
    for k in range(20):
        clock[0] = 0.2 + 0.005 * (k + 1)
        reader.poll(clock[0])
    assert reader.run_enable_drops[0]["cause"] == "reset (watchdog)"
    assert not fw.run_enable and not reader.run_enable, "a new boot re-armed itself"
    reader.rearm_supervisor()  # the operator's re-arm after the reset
    for k in range(10):
        clock[0] = 0.3 + 0.005 * k
        reader.poll(clock[0])
    assert fw.run_enable and reader.run_enable
    # the host stops; the Nano drops; the host comes back and learns why
    clock[0] = 1.0
    fw.service(1.0)
    reader.poll(1.0)
    reader.poll(1.01)
    assert reader.run_enable_drops[-1]["cause"] == "heartbeat" and reader.run_enable is False
    assert not fw.run_enable  # latched: polling alone does not turn it on
    reader.rearm_supervisor()  # the operator's re-arm
    for k in range(10):
        clock[0] = 1.02 + 0.005 * k
        reader.poll(clock[0])
    assert fw.run_enable and reader.run_enable


def test_a_stripped_supervisor_event_hands_its_gap_to_the_next_event():
    fw = EmulatedFirmware(ring_capacity=4)
    clock = [0.0]
    reader = make_reader("v2", _EmuTransport(fw, clock), supervisor_command=LIMITS)
    reader.poll(0.0)
    reader.poll(0.001)
    # overflow, then the next event that gets in is the supervisor's drop (GAP), then a Hall edge
    _edges(fw, "primary", 3000.0, 0.002, 0.2)
    assert fw.overflow
    clock[0] = 0.25
    fw.service(0.25)  # the heartbeat drop (nobody polled since 0.001)
    edges = []
    for k in range(40):
        clock[0] = 0.25 + 0.001 * k
        if k == 2:
            fw.capture("primary", clock[0])
        edges += [e for e in reader.poll(clock[0]) if e.channel == v1.CH_PRIMARY]
    assert all(e.channel != v2.CH_SUPERVISOR for e in edges)
    assert any(e.gap for e in edges), "the hole before the supervisor's event must stay marked"


def test_new_host_old_firmware_finds_it_absent_and_keeps_reading():
    from dyno.acquisition.reader import run_enable_text

    for fw in (EmulatedFirmware(supervisor=False), EmulatedFirmware(knows_caps=False)):
        clock = [0.0]
        reader = make_reader("v2", _EmuTransport(fw, clock), supervisor_command=LIMITS)
        got = []
        for k in range(40):
            clock[0] = 0.005 * k
            fw.capture("primary", clock[0] - 0.001) if k else None
            got += reader.poll(clock[0])
        assert reader.supervisor_present is False and run_enable_text(reader) == "absent"
        assert len([e for e in got if e.channel == v1.CH_PRIMARY]) >= 30  # the link goes on


def test_old_host_new_firmware_never_sees_tag_5_or_run():
    """A host without the feature never sends SET_SUPERVISOR: the firmware never arms, never queues tag 5 nor
    sets RUN (which an old decoder would refuse), and the output stays off: the engine cannot run on a rig
    whose kill chain has the Nano's enable in it (docs/safety.md)."""
    fw = EmulatedFirmware()
    for k in range(50):
        t = 0.005 * k
        fw.capture("primary", t)
        fw.write(v2.poll(), t)
        fr = v2.decode_frame(fw.read(32, t))
        assert not fr.flags & v2.FLAG_RUN and all(e.channel != v2.CH_SUPERVISOR for e in fr.events)
        fw.write(v2.poll((fr.boot_id, fr.seq)), t)
    assert not fw.run_enable
