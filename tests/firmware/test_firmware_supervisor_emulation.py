"""The run-enable supervisor: the real firmware (simavr) and its Python emulation on the same stimulus.

The firmware runs with the harness's Hall and ADC generators while the real host reader polls it, arms it
with the shipped limits and (heartbeat case) stops polling for 0.5 s. Every Hall edge and conversion the
firmware timestamped, and every host transaction at its simulated time, are then replayed into
:class:`dyno.sim.device.EmulatedFirmware`; the two must agree frame for frame on what the supervisor put in
them: the same tag-5 events in the same order (cause and measured value exactly, time within one loop pass
and a bus transfer), and for every read the same RUN flag (except for a read within a loop pass of a
change, where the firmware's pre-built frame may lag by one).
"""

import pytest

from dyno.acquisition.reader import make_reader
from dyno.protocol import v2
from dyno.protocol import v1
from dyno.sim.device import EmulatedFirmware
from dyno.transports.simavr import SimavrTransport

pytestmark = pytest.mark.slow

LIMITS = v2.supervisor_command(4200.0, 7800.0, 0.2)
#: the firmware dates a heartbeat from the loop pass that took it (< 1 ms) after the command, and a
#: transfer's own write takes up to ~1 ms at 100 kHz: the emulation dates both at the transfer's start
TIME_TOL_US = 2500
CHANNEL = {1: "primary", 2: "secondary", 3: "adc"}


class _Recorder(SimavrTransport):
    """The harness transport, keeping every transaction (sim time at its start, request, read length, answer)."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.log = []

    def _transfer(self, request, read_len):
        t_us = self.sync()  # the instant the transfer starts (after the transfers before it in this tick)
        out = super()._transfer(request, read_len)
        self.log.append((t_us, bytes(request), read_len, out))
        return out


def _firmware_run(build, primary_rpm, stop_s=None, resume_s=None, end_s=1.6):
    tr = _Recorder(build["elf"], harness=build["harness"], primary_rpm=primary_rpm, secondary_rpm=7000.0)
    events = []
    try:
        reader = make_reader("v2", tr, supervisor_command=LIMITS)
        reader.session.frame_listeners.append(
            lambda raw: events.extend(v2.decode_frame(raw.ljust(32, b"\0")).events))
        k = 1
        while k / 150 < end_s or (stop_s is not None and not any(e.channel == v2.CH_SUPERVISOR and e.status
                                                               == v2.SUP_HEARTBEAT for e in events)):
            t = k / 150
            k += 1
            if stop_s is not None and stop_s <= t < resume_s:
                continue
            tr.advance_to(t)
            reader.poll(t)
    finally:
        tr.close()
    return tr.log, events


def _emulate(log, events):
    """Replay the firmware's own timestamps (device us = simulated us) and the host's transactions."""
    fw = EmulatedFirmware()
    fw.boot_id = next(r[5] << 8 | r[6] for _, _, _, r in log if len(r) >= 32 and r[2] == v1.KIND_DATA)
    # The host's instants on the device's clock: micros() starts after the MCU's start-up and a command
    # acts when its bytes are in, so the offset is taken where both clocks saw one thing, the arming
    t_sup = next(t for t, req, _, _ in log if req[:1] == bytes([v2.OP_SET_SUPERVISOR]))
    t_on = next(e.t_us for e in events if e.channel == v2.CH_SUPERVISOR and e.status == v2.SUP_ON)
    offset_us = t_on - t_sup
    feed = [(e.t_us, 0, e) for e in events if e.channel in CHANNEL]
    feed += [(t_us + offset_us, 1, (req, n)) for t_us, req, n, _ in log]
    feed.sort(key=lambda x: (x[0], x[1]))
    answers = []
    for t_us, kind, item in feed:
        t = t_us / 1e6
        if kind == 0:
            fw.capture(CHANNEL[item.channel], t, item.code, item.status)
        else:
            req, n = item
            fw.service(t)
            fw.write(req, t)
            answers.append(fw.read(n, t) if n else b"")
    return answers, offset_us


def _sup(raws):
    """The tag-5 events of each distinct data frame (a frame read again unacknowledged counts once)."""
    out, seen = [], set()
    for raw in raws:
        if len(raw) < 32 or raw[2] != v1.KIND_DATA:
            continue
        try:
            f = v2.decode_frame(raw)
        except Exception:  # noqa: BLE001 - (a CAPS answer or a rejected read: not a data frame)
            continue
        if (f.boot_id, f.seq) in seen:
            continue
        seen.add((f.boot_id, f.seq))
        out += [(e.status, e.code, e.t_us) for e in f.events if e.channel == v2.CH_SUPERVISOR]
    return out


def _run_flags(raws):
    return [bool(r[4] & v2.FLAG_RUN) if len(r) >= 32 and r[2] == v1.KIND_DATA else None for r in raws]


def _compare(log, events):
    fw_answers = [a for _, _, n, a in log]
    emu_answers, offset_us = _emulate(log, events)
    fw_sup, emu_sup = _sup(fw_answers), _sup(emu_answers)
    assert [(s, c) for s, c, _ in fw_sup] == [(s, c) for s, c, _ in emu_sup], (fw_sup, emu_sup)
    for (_, _, t_fw), (_, _, t_emu) in zip(fw_sup, emu_sup):
        assert abs(t_fw - t_emu) <= TIME_TOL_US, (t_fw, t_emu)
    fw_run, emu_run = _run_flags(fw_answers), _run_flags(emu_answers)
    changes = [t for _, _, t in fw_sup]
    differ = [i for i, (a, b) in enumerate(zip(fw_run, emu_run)) if a is not None and b is not None and a != b]
    for i in differ:  # only a read within a loop pass + a transfer of a change may see the other side of it
        assert any(abs(log[i][0] + offset_us - t) <= TIME_TOL_US for t in changes), (i, log[i][0], changes)
    return fw_sup, sum(1 for x in fw_run if x is not None), len(differ)


def test_heartbeat_drop_the_same_in_firmware_and_emulation(firmware_build):
    log, events = _firmware_run(firmware_build, 3800.0, stop_s=1.0, resume_s=1.5)
    sup, n_frames, n_differ = _compare(log, events)
    assert [s for s, _, _ in sup] == [v2.SUP_ON, v2.SUP_HEARTBEAT] and sup[1][1] == 200
    assert n_frames > 150 and n_differ <= 2


def test_overspeed_drop_the_same_in_firmware_and_emulation(firmware_build):
    log, events = _firmware_run(firmware_build, 4600.0, end_s=0.8)
    sup, n_frames, n_differ = _compare(log, events)
    assert [s for s, _, _ in sup] == [v2.SUP_ON, v2.SUP_OVERSPEED_PRIMARY]
    # the period as the edges' ISRs dated them: each may wait out a critical section of the loop or another ISR
    # (a few us at 16 MHz; where the edges fall in the loop's passes moves with any change to the loop's code)
    assert sup[1][1] == pytest.approx(60e6 / 4600.0, abs=8)
    assert n_frames > 80 and n_differ <= 2
