"""Issue 49, item 1 on the real firmware: the heartbeat the Nano hears proves the host's control loop ticked.

The real ELF in simavr, armed with hardware/rig.toml's limits (0.2 s heartbeat timeout) by the host's own reader,
polled by the host's own :class:`~dyno.acquisition.poller.Poller` with its I/O thread (``blocking_io``) on a real
asyncio loop.  Simulated time follows the host's clock (a world thread runs the simulation to it every 5 ms, so
the Nano's time passes whether or not anyone polls).  Then the loop is frozen (``time.sleep`` on it) while the I/O
thread runs on: the I/O thread stops the heartbeat within the loop tolerance, and D7 (the run-enable, as the
harness sees the pin) drops the heartbeat timeout after the last poll, while the loop is still frozen.  Every
figure is on the simulation's clock (the pin's truth), none on the wall clock.
"""

from __future__ import annotations

import asyncio
import threading
import time

import pytest

from dyno.acquisition.poller import LOOP_TOLERANCE_S, Poller
from dyno.acquisition.reader import make_reader
from dyno.protocol import v2
from dyno.transports.base import Transport
from dyno.transports.simavr import SimavrTransport

pytestmark = pytest.mark.firmware

TIMEOUT_S = 0.2  # hardware/rig.toml [limits] supervisor_timeout_s
POLL_HZ = 150.0
START_S = 0.05  # the harness's own start (its --start-us default)


class _OnTheHostClock(Transport):
    """The simavr transport with simulated time = the host's monotonic clock since the start; a world thread
    steps it meanwhile.  One lock: the harness is one pipe."""

    name = "simavr-on-host-clock"

    def __init__(self, sim: SimavrTransport) -> None:
        super().__init__()
        self.sim = sim
        self.lock = threading.Lock()
        self.t0 = time.monotonic()
        self.sent_at_s: list[float] = []  # the simulated instant of every transfer (a heartbeat each)
        self._stop = threading.Event()
        self._world = threading.Thread(target=self._run_world, daemon=True)
        self._world.start()

    def sim_s(self) -> float:
        return START_S + time.monotonic() - self.t0

    def _run_world(self) -> None:
        while not self._stop.wait(0.005):
            with self.lock:
                self.sim.advance_to(self.sim_s())
                self.sim.sync()

    def _transfer(self, request: bytes, read_len: int) -> bytes:
        with self.lock:
            t = self.sim_s()
            self.sim.advance_to(t)
            data = self.sim.transfer(request, read_len)
            self.sent_at_s.append(self.sim.sim_time_us / 1e6 if self.sim.sim_time_us else t)
            return data

    def stats(self) -> dict:
        with self.lock:
            return self.sim.harness_stats()

    def close(self) -> None:
        self._stop.set()
        self._world.join(timeout=30)
        self.sim.close()


def test_a_frozen_loop_stops_the_heartbeat_and_d7_drops_while_the_io_thread_runs(firmware_build):
    sim = SimavrTransport(firmware_build["elf"], harness=firmware_build["harness"], primary_rpm=3000.0,
                          secondary_rpm=6000.0)
    link = _OnTheHostClock(sim)
    reader = make_reader("v2", link, supervisor_command=v2.supervisor_command(4200.0, 7800.0, TIMEOUT_S))
    poller = Poller(reader, poll_hz=POLL_HZ, blocking_io=True)
    seen: dict = {}

    async def main() -> None:
        task = asyncio.create_task(poller.run())
        deadline = time.monotonic() + 60.0  # generous: the first frames of a boot on a loaded machine
        while not reader.run_enable and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
        assert reader.run_enable, "the host never armed the run-enable"
        seen["armed_s"] = link.sim_s()
        await asyncio.sleep(0.5)  # a live loop: the heartbeat goes on, D7 stays on
        seen["held_before"] = poller.held_ticks
        seen["freeze_s"] = link.sim_s()
        polls0 = poller.polls
        time.sleep(1.0)  # the loop is frozen; the I/O thread is not
        seen["resume_s"] = link.sim_s()
        seen["polls_during"] = poller.polls - polls0
        seen["held_during"] = poller.held_ticks - seen["held_before"]
        t_back = time.monotonic() + 30.0
        while not reader.run_enable_drops and time.monotonic() < t_back:  # the host reads what happened
            await asyncio.sleep(0.02)
        poller.stop()
        await task

    try:
        asyncio.run(main())
        hs = link.stats()
    finally:
        link.close()
    transitions = hs["run_enable"]["transitions"]
    ons = [t / 1e6 for t, level in transitions if level]
    offs = [t / 1e6 for t, level in transitions if not level]
    assert ons and ons[0] < seen["armed_s"]
    # no drop while the loop was alive (the 0.5 s before the freeze)
    assert not [t for t in offs if t < seen["freeze_s"]], (offs, seen)
    assert offs, f"D7 never dropped: {seen}"
    off_s = offs[0]
    # the I/O thread ran all through: it polled a few ticks (within the loop tolerance), then held the rest
    assert seen["held_before"] == 0 and seen["held_during"] > 0, seen
    assert 1 <= seen["polls_during"] <= (LOOP_TOLERANCE_S + 0.05) * POLL_HZ * 8, seen  # (8: a burst's polls)
    last_poll_s = max(t for t in link.sent_at_s if t < off_s)
    # the heartbeat stopped within the loop tolerance (+ a poll period and the pipe's lock) of the freeze
    assert last_poll_s - seen["freeze_s"] <= LOOP_TOLERANCE_S + 0.05, (last_poll_s, seen)
    # D7 dropped the timeout after the last heartbeat (+ the firmware's loop pass and the transfer), while the
    # loop was still frozen
    assert TIMEOUT_S < off_s - last_poll_s <= TIMEOUT_S + 0.002 + 0.004, (off_s, last_poll_s)
    assert off_s - seen["freeze_s"] <= TIMEOUT_S + LOOP_TOLERANCE_S + 0.05
    assert off_s < seen["resume_s"]
    # the host, back, learns it from the device: a heartbeat drop
    assert reader.run_enable_drops and reader.run_enable_drops[0]["cause"] == "heartbeat"
