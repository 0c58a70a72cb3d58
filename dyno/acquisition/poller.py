"""The asyncio poller: reads the device at a fixed rate, keeps the streams.

One task.  Each tick: poll the reader (again at once, a bounded number of
times, while the device says MORE), append the events to the streams, hand
them to the listeners (the run log, the safety check), and every
``temp_period_s`` read the rotor thermometer.  Time comes from the running
loop, so under :class:`dyno.clock.VirtualTimeLoop` the same code runs faster
than real time.

How a tick is driven (a sleeping coroutine or one paced I/O thread, not a
thread hop per tick: the cheaper in CPU for each kind of transport):

* non-blocking transports (the simulated bus): the task polls synchronously and sleeps to the
  next tick (a ``loop.call_at`` timer would save a loop iteration per tick, but it changes the
  order of same-instant wake-ups the speed hold was tuned with, see :meth:`run`);
* blocking transports (a real I2C or serial bus): one I/O thread paces the
  transfers itself and hands each tick's result to the loop with one
  ``call_soon_threadsafe``; streams, listeners and the safety check still
  run on the loop, in tick order.  A hung transfer blocks only that thread:
  the loop's heartbeat sees the link silent (``comms_lost``).

Liveness (issue 49): every poll is the Nano's heartbeat, so a poll must prove that the control loop is alive,
not only its I/O thread.  The loop stamps :attr:`Poller.loop_alive_s` (its own clock) each time it has handled
a tick, after the listeners (the safety check) ran; the I/O thread polls only while that stamp is at most
:data:`LOOP_TOLERANCE_S` old.  A blocked loop, a call deadlocked on it or a plan hogging it stops the polls
and so the heartbeat within that tolerance, although the thread itself runs on; the Nano then opens the kill
chain ``supervisor_timeout_s`` later.  The thread asks the loop for a fresh stamp (one pending callback) and
polls again the moment the loop has answered.
"""

from __future__ import annotations

import asyncio
import math
import threading
from dataclasses import dataclass, field

import numpy as np

from dyno.acquisition.rpm import current_rpm
from dyno.acquisition.streams import Streams
from dyno.protocol import v1
from dyno.protocol.v2 import cause_name

#: How old the control loop's last stamp may be while the I/O thread still polls (the Nano's heartbeat): a loop
#: late by more than this plus the Nano's timeout (0.05 + 0.2 s with hardware/rig.toml) gets the engine cut.
#: Small, so that a freeze is cut within supervisor_timeout_s + 0.1 s of its start (docs/safety.md).
LOOP_TOLERANCE_S = 0.05
MAX_HOLDS_KEPT = 1000  # holds recorded one by one (all are counted in held_ticks)


@dataclass
class PollTiming:
    """Poll-interval statistics (for the link-health display and benchmarks).

    ``intervals_s``: the latest intervals (at most ``keep``); ``rates``: every interval of the run, by the
    nominal period that scheduled it (a histogram of 20 us bins: one dict update per tick), so that the
    rate the poller held and its jitter are known for the whole run at each rate it polled at.
    """

    intervals_s: list = field(default_factory=list)
    keep: int = 20000
    rates: dict = field(default_factory=dict)  # nominal period (s) -> [ticks, sum of intervals, max, {bin: count}]

    BIN_S = 20e-6

    def add(self, dt_s: float, nominal_s: float | None = None) -> None:
        self.intervals_s.append(dt_s)
        if len(self.intervals_s) > self.keep:
            del self.intervals_s[: self.keep // 2]
        if nominal_s is not None:
            r = self.rates.get(nominal_s)
            if r is None:
                r = self.rates[nominal_s] = [0, 0.0, 0.0, {}]
            r[0] += 1
            r[1] += dt_s
            if dt_s > r[2]:
                r[2] = dt_s
            hist = r[3]
            b = int(dt_s / self.BIN_S + 0.5)
            hist[b] = hist.get(b, 0) + 1

    def summary(self) -> dict:
        if not self.intervals_s:
            return {"polls": 0}
        a = np.asarray(self.intervals_s)
        out = {"polls": int(a.size), "mean_ms": float(a.mean() * 1e3), "std_ms": float(a.std() * 1e3),
               "p99_ms": float(np.percentile(a, 99) * 1e3), "max_ms": float(a.max() * 1e3)}
        if self.rates:
            out["by_rate"] = self.by_rate()
        return out

    def by_rate(self) -> list[dict]:
        """Per nominal rate, over the whole run: ticks, the rate held (ticks per second of their intervals),
        jitter p99 (|interval - median|, ms) and lateness p99 (interval - nominal period, ms) to the histogram's
        20 us, the longest interval."""
        out = []
        for nominal_s, (n, total_s, max_s, hist) in sorted(self.rates.items()):
            bins = np.array(sorted(hist))
            counts = np.array([hist[int(b)] for b in bins], dtype=float)
            dt = bins * self.BIN_S
            cum = np.cumsum(counts)
            median = dt[np.searchsorted(cum, 0.5 * n)]
            dev = np.abs(dt - median)
            order = np.argsort(dev, kind="stable")
            dev_p99 = dev[order][np.searchsorted(np.cumsum(counts[order]), 0.99 * n)]
            out.append({"nominal_hz": round(1.0 / nominal_s, 3), "polls": int(n),
                        "held_hz": round(n / total_s, 3) if total_s > 0 else None,
                        "jitter_p99_ms": round(float(dev_p99 * 1e3), 3),
                        "late_p99_ms": round(float(dt[np.searchsorted(cum, 0.99 * n)]
                                                   - round(nominal_s / self.BIN_S) * self.BIN_S) * 1e3, 3),
                        "max_ms": round(max_s * 1e3, 3)})
        return out


class Poller:
    def __init__(self, reader, *, poll_hz: float = 150.0, thermometer=None, temp_period_s: float = 0.1,
                 max_burst: int = 8, blocking_io: bool = False) -> None:
        self.reader = reader
        self.full_poll_hz = poll_hz  # the rig's rate (rig.toml poll_hz); set_poll_hz() may lower it for a while
        self._periods_per_tick = 1
        self.poll_period_s = 1.0 / poll_hz
        self.thermometer = thermometer
        self.temp_period_s = temp_period_s
        self.max_burst = max_burst
        self.blocking_io = blocking_io  # real buses: run transfers in a thread
        self.streams = Streams()
        self.listeners: list = []  # callables(events, now_s)
        self.timing = PollTiming()
        self.rotor_temp_c: float = math.nan
        self.rotor_temp_time_s: float = math.nan
        self.temp_errors = 0
        self.last_valid_frame_s: float | None = None
        self.last_poll_s: float | None = None  # last attempt, valid or not (link silence vs host stall)
        self.started_s: float | None = None
        self.polls = 0
        # What makes a measurement window untrustworthy: events lost, a device reset,
        # a poll gap (the loop stalled).  dicts {host_t_s, kind, detail}; the controller
        # discards a point whose window contains one.
        self.disturbances: list[dict] = []
        self.epoch_start_us: int | None = None  # first event time of the device's current boot
        self._lost_seen = 0
        self._resets_seen = 0
        self._last_poll_s: float | None = None
        self._device_us: int | None = None
        self._stop = asyncio.Event()
        self._last_temp_s = -math.inf
        # the control loop's last sign of life (its clock): the I/O thread's polls wait for a fresh one
        self.loop_tolerance_s = LOOP_TOLERANCE_S
        self.loop_alive_s: float | None = None
        self.held_ticks = 0  # ticks the I/O thread did not poll because the loop's stamp was stale
        self.holds: list[dict] = []  # {"from_s", "to_s"} (I/O thread's clock): the heartbeat withheld
        self._nudge_pending = False
        self._io_read_s = math.inf  # when the I/O thread (or its stand-in) last read a tick

    # --- the task ------------------------------------------------------------------
    async def run(self) -> None:
        """Poll until :meth:`stop`; an exception raised by a tick (a listener's, a reader's) ends it here."""
        loop = asyncio.get_running_loop()
        self._loop = loop
        self._error: BaseException | None = None
        self.started_s = self._next_t = loop.time()
        self.loop_alive_s = self.started_s
        self._last_tick_s = None
        if self.blocking_io:
            io_stop = threading.Event()
            thread = threading.Thread(target=self._io_thread, args=(loop, io_stop), name="dyno-poller-io",
                                      daemon=True)  # daemon: a transfer hung in the kernel must not hang exit
            thread.start()
            try:
                await self._stop.wait()
            finally:
                io_stop.set()  # not joined: a hung transfer must not block the loop
        else:
            # Ticks in this task, not as a loop timer: a timer callback runs before the tasks waking
            # at the same instant, and the speed hold is tuned to this order (the controller sees its
            # data one poll earlier at the instants it shares with the polls; under the timer's order
            # its step response is several times slower, bench/bench_test_time.py).
            next_t = self._next_t
            full_period_s = 1.0 / self.full_poll_hz
            stall_ticker = _stall_ticker(self, loop)
            scheduled_s = self.poll_period_s  # the period that scheduled this tick (its interval's nominal)
            while not self._stop.is_set():
                now = loop.time()
                self._note_interval(now, scheduled_s)
                self._end_hold(now)
                self._finish_poll(now, *self._read_burst(now), self._read_temperature(now))
                self.loop_alive_s = loop.time()
                for _ in range(self._periods_per_tick):
                    next_t += full_period_s
                scheduled_s = self.poll_period_s
                now = loop.time()
                if next_t < now:  # fell behind: skip ticks rather than bunch them
                    next_t = now
                await asyncio.sleep(next_t - now)
            if stall_ticker is not None:
                loop.remove_ticker(stall_ticker)
        if self._error is not None:
            raise self._error

    def _io_thread(self, loop, io_stop: threading.Event) -> None:
        """Blocking transports: transfers paced in this thread, each tick's result handed to the loop."""
        next_t = loop.time()  # a real loop's clock is time.monotonic(): usable from any thread
        scheduled_s = self.poll_period_s  # the period that scheduled this tick (its interval's nominal)
        while not io_stop.is_set():
            now = loop.time()
            if not self.loop_fresh(now):  # the loop is not handling ticks: no heartbeat for the Nano
                self._hold(loop, now, threadsafe=True)
                io_stop.wait(self.poll_period_s)
                continue
            self._reading(now)
            try:
                result = (now, *self._read_burst(now), self._read_temperature(now))
            except Exception as exc:
                result = exc
            try:
                loop.call_soon_threadsafe(self._deliver, result, scheduled_s)
            except RuntimeError:  # the loop is closed: nothing left to deliver to
                return
            if isinstance(result, Exception):
                return
            scheduled_s = self.poll_period_s
            next_t += scheduled_s
            now = loop.time()
            if next_t < now:
                next_t = now
            io_stop.wait(next_t - now)

    def _deliver(self, result, scheduled_s: float | None = None) -> None:
        """On the loop: one I/O-thread tick's events to the streams, listeners and safety, in order.

        A tick read before :meth:`stop` and handed over after it is still delivered: its frames
        were acknowledged, so the device has retired their events and this is their only copy.
        """
        if isinstance(result, Exception):
            if not self._stop.is_set():
                self._error = result
                self._stop.set()
            return
        now = result[0]
        self._note_interval(now, scheduled_s)
        lag_s = self._loop.time() - now
        if lag_s > self._gap_limit_s():  # the loop stalled: actions and checks ran late in this window
            self.disturbances.append({"host_t_s": now, "kind": "poll_gap",
                                      "detail": f"tick handled {lag_s:.3f} s late (host loop stalled)"})
        try:
            self._finish_poll(*result)
        except Exception as exc:
            if not self._stop.is_set():
                self._error = exc
                self._stop.set()
        self.loop_alive_s = self._loop.time()

    # --- the loop's liveness (module doc) -------------------------------------------------
    def loop_fresh(self, now_s: float) -> bool:
        """May the I/O thread poll at ``now_s``: has the loop stamped within :attr:`loop_tolerance_s`?"""
        alive = self.loop_alive_s
        # (or it has handled the last tick the thread read: a poll rate lowered below 1 / tolerance polls on)
        return alive is None or now_s - alive <= self.loop_tolerance_s or alive >= self._io_read_s

    def _hold(self, loop, now_s: float, *, threadsafe: bool) -> None:
        """A tick not polled (any thread): counted, its hold recorded, the loop asked once to stamp."""
        self.held_ticks += 1
        if (not self.holds or self.holds[-1]["to_s"] is not None) and len(self.holds) < MAX_HOLDS_KEPT:
            self.holds.append({"from_s": now_s, "to_s": None})
        if not self._nudge_pending:
            self._nudge_pending = True
            try:
                (loop.call_soon_threadsafe if threadsafe else loop.call_soon)(self._nudged)
            except RuntimeError:  # the loop is closed
                pass

    def _reading(self, now_s: float) -> None:
        """The I/O thread (or its stand-in) reads a tick at ``now_s``: any hold ends."""
        self._end_hold(now_s)
        self._io_read_s = now_s

    def _end_hold(self, now_s: float) -> None:
        if self.holds and self.holds[-1]["to_s"] is None:
            self.holds[-1]["to_s"] = now_s

    def _nudged(self) -> None:
        self._nudge_pending = False
        self.loop_alive_s = self._loop.time()

    def _note_interval(self, now: float, scheduled_s: float | None = None) -> None:
        if self._last_tick_s is not None:
            self.timing.add(now - self._last_tick_s, scheduled_s)
        self._last_tick_s = now

    def stop(self) -> None:
        self._stop.set()

    def set_poll_hz(self, hz: float | None) -> None:
        """Poll at ``hz`` from the next tick on (None: the rig's full rate), as a whole number of full-rate
        periods: the ticks stay on the full-rate grid (same-instant order with the other tasks unchanged)."""
        hz = self.full_poll_hz if hz is None else min(float(hz), self.full_poll_hz)
        self._periods_per_tick = max(1, round(self.full_poll_hz / hz))
        self.poll_period_s = self._periods_per_tick / self.full_poll_hz

    def disturbances_between(self, t0_s: float, t1_s: float) -> list[dict]:
        """Disturbances recorded in ``[t0_s, t1_s]`` (host time), plus a poll gap still open at ``t1_s``."""
        out = [d for d in self.disturbances if t0_s <= d["host_t_s"] <= t1_s]
        last = self._last_poll_s
        if last is not None and t1_s - last > self._gap_limit_s():
            out.append({"host_t_s": last, "kind": "poll_gap", "detail": f"no poll for {t1_s - last:.3f} s"})
        return out

    def _gap_limit_s(self) -> float:
        return max(0.1, 10.0 * self.poll_period_s)

    def _note_disturbances(self, now_s: float) -> None:
        r = self.reader
        lost = r.events_lost
        if lost > self._lost_seen:
            self.disturbances.append({"host_t_s": now_s, "kind": "events_lost",
                                      "detail": f"{lost - self._lost_seen} events lost"})
            self._lost_seen = lost
        resets = r.stats.device_resets
        if resets > self._resets_seen:
            cause = getattr(r, "reset_cause", None)  # v2 frames carry it
            why = "" if cause is None else f", cause {cause_name(cause)}"
            self.disturbances.append({"host_t_s": now_s, "kind": "device_reset",
                                      "detail": f"device reset ({resets - self._resets_seen}{why})"})
            self._resets_seen = resets
        last = self._last_poll_s
        if last is not None and now_s - last > self._gap_limit_s():
            self.disturbances.append({"host_t_s": last, "kind": "poll_gap",
                                      "detail": f"no poll for {now_s - last:.3f} s (host stalled)"})
        self._last_poll_s = now_s

    async def poll_once(self, now_s: float) -> list:
        """One tick by hand (tests, tools): read, then streams, listeners and thermometer."""
        if self.blocking_io:
            burst = await asyncio.to_thread(self._read_burst, now_s)
            temp = await asyncio.to_thread(self._read_temperature, now_s)
        else:
            burst, temp = self._read_burst(now_s), self._read_temperature(now_s)
        return self._finish_poll(now_s, *burst, temp)

    def _read_burst(self, now_s: float) -> tuple[list, bool, int | None]:
        """The bus part of a tick (any thread): the reader polled while the device says MORE.

        Returns the events, whether a frame was accepted, the first event time of a
        new boot (None if no reset was seen) and the device time known after the burst.
        """
        events: list = []
        accepted = False
        new_epoch_us = None
        reader = self.reader
        for _ in range(self.max_burst):
            accepted_before = reader.stats.accepted
            resets_before = reader.stats.device_resets
            new = reader.poll(now_s)
            self.polls += 1
            if reader.stats.device_resets > resets_before:
                # A new boot: its edges must never pair with the old boot's (the gap between
                # the two time bases is only estimated), so speeds restart from its own edges.
                new_epoch_us = min((e.t_us for e in new), default=reader.device_time_us)
            if reader.stats.accepted > accepted_before:
                accepted = True
            events.extend(new)
            if not reader.more:
                break
        return events, accepted, new_epoch_us, reader.device_time_us

    def _read_temperature(self, now_s: float):
        """The rotor thermometer every ``temp_period_s`` (any thread): a float, an exception, or None."""
        if self.thermometer is None or now_s - self._last_temp_s < self.temp_period_s:
            return None
        self._last_temp_s = now_s
        try:
            return float(self.thermometer())
        except Exception as exc:  # a failed read keeps the last value; counted, monitored
            return exc

    def _finish_poll(self, now_s: float, events: list, accepted: bool, new_epoch_us, device_us, temp) -> list:
        """The loop's part of a tick: streams, disturbances, listeners (run log, safety), temperature.

        ``device_us``: the device time the reader knew when this tick was read — not the reader's latest, which
        an I/O thread may have moved on (ticks read during a loop stall are handled after it, in order)."""
        self.last_poll_s = now_s
        if device_us is not None:
            self._device_us = device_us
        if new_epoch_us is not None:
            self.epoch_start_us = new_epoch_us
        if accepted:
            self.last_valid_frame_s = now_s
        if events:
            self.streams.extend(events)
        self._note_disturbances(now_s)
        if temp is not None:
            if isinstance(temp, Exception):
                self.temp_errors += 1
            else:
                self.rotor_temp_c = temp
                self.rotor_temp_time_s = now_s
        for listener in self.listeners:
            listener(events, now_s)
        return events

    # --- live values ------------------------------------------------------------------
    def device_now_us(self) -> int | None:
        """The device's time as of the last tick handled (the streams hold its events up to then)."""
        return self._device_us if self._device_us is not None else self.reader.device_time_us

    def rpm(self, channel: int) -> float:
        now = self.device_now_us()
        if now is None:
            return 0.0
        edges = self.streams.last_edges(channel)
        if self.epoch_start_us is not None and len(edges) >= 2 and edges[-2] < self.epoch_start_us:
            return 0.0  # no two edges of this boot yet: no speed, never one across the reset
        if getattr(self.reader, "protocol", None) == "v0" and len(edges) >= 1:
            # v0 misses edges between polls: two edges the host saw may be several periods
            # apart.  The device's own period (the rpm slot) is the speed; staleness as below.
            slot_rpm = float(self.streams.edge_rpm[channel][-1])
            if slot_rpm <= 0:
                return 0.0
            period_us = 60e6 / slot_rpm
            quiet_us = now - int(edges[-1])
            if quiet_us > min(500_000, 3.0 * period_us) and quiet_us > period_us:
                return 0.0
            return slot_rpm
        if len(edges) >= 2 and self.streams.edge_gap[channel][-1]:
            # events were lost between the last two edges: the latest period without a loss
            pair = self.streams.last_valid_pair(channel)
            if pair is None:
                return 0.0
            period = int(pair[1]) - int(pair[0])
            quiet = now - int(edges[-1])  # staleness judged from the newest edge
            if period <= 0 or (quiet > min(500_000, 3 * period) and quiet > period):
                return 0.0
            return 60e6 / period
        return current_rpm(edges, now)

    def latest_adc(self) -> tuple[int, int] | None:
        s = self.streams
        return (s.adc_code[-1], s.adc_status[-1]) if s.adc_t else None

    def link_health(self) -> dict:
        st = self.reader.stats.as_dict()
        st["events_lost"] = self.reader.events_lost
        st["polls"] = self.polls
        st["poll_timing"] = self.timing.summary()
        return st


CHANNELS = {"primary": v1.CH_PRIMARY, "secondary": v1.CH_SECONDARY}


def _stall_ticker(poller: "Poller", loop):
    """On a virtual-time loop: keep polling while a callback holds the loop (drill ``loop-stall``), as the
    rig's I/O thread does (``blocking_io``): the Nano's heartbeat and its ring are served; the ticks are
    handled when the loop is free again, late (``_deliver`` notes the gap).  None on other loops."""
    if not hasattr(loop, "add_ticker"):
        return None

    def tick() -> None:
        if loop.blocked and not poller._stop.is_set():
            now = loop.time()
            if not poller.loop_fresh(now):  # as the I/O thread: no heartbeat while the loop is stale
                poller._hold(loop, now, threadsafe=False)
                return
            poller._reading(now)
            result = (now, *poller._read_burst(now), poller._read_temperature(now))
            loop.call_soon(poller._deliver, result, poller.poll_period_s)
    return loop.add_ticker(tick, poller.poll_period_s)

