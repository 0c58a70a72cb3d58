"""The rig's outputs on Raspberry Pi GPIO (gpiozero), behind :class:`Actuators`.

Ported from the thesis Pi code (Messick 2018, App. H: ``apply_brake``,
``step_brake``, ``set_throttle``, ``reset_arduino``, ``E_STOP``) with the
hazards that code left open closed:

* The direction relay is never switched while the actuator enable MOSFET is
  on: switching a DPDT relay under motor current arcs its contacts and, for a
  moment, shorts the supply through the H-bridge wiring.  Order is always
  enable off -> settle -> relay -> settle -> enable on.
* Travel is integrated from enable-on time so the actuator is de-energised at
  its end stops instead of stalling against the internal limit switch forever.
* Nothing blocks except the explicit blocking helpers (:meth:`step`,
  :meth:`reset_arduino`, :meth:`finish_release`): the controller's loop drives
  time-based behaviour through :meth:`tick`, as the ``Actuators`` contract asks.

Relay polarity (``brake_direction`` energised = APPLY) follows the thesis
board: RELEASE is the relay's rest state, so a safe-state release needs only
the enable.
"""

from __future__ import annotations

import math
import threading
from contextlib import contextmanager

from gpiozero import DigitalInputDevice, DigitalOutputDevice, PWMOutputDevice

from dyno.control.outputs import APPLY, RELEASE, STOP
from dyno.errors import SafetyAbort
from dyno.clock import MonotonicClock
from dyno.hw.endswitch import EndSwitch, tolerance
from dyno.hw.blocking import BlockingMixin
from dyno.hw.readback import ReadbackMixin
from dyno.rig.config import RigConfig

#: Keep driving into an end stop for this fraction of a stroke beyond the
#: estimate, so estimate drift never leaves the brake short of its stop.
END_STOP_OVERRUN_FRACTION = 0.10


class GpioActuators(BlockingMixin, ReadbackMixin):
    """Brake actuator, throttle servo, engine kill and Arduino reset on GPIO.

    Parameters
    ----------
    config : RigConfig
    pin_factory : gpiozero pin factory, optional
        ``MockFactory`` in tests; ``None`` lets gpiozero pick (lgpio on a Pi 5).
    clock : object with ``now()`` and ``sleep(s)``, optional
        :class:`dyno.clock.MonotonicClock` by default.

    Construction puts every output in its safe value at once (throttle idle,
    engine killed, brake enable off, relay at rest) and starts a release
    stroke, because the brake position at start-up is unknown.
    """

    def __init__(self, config: RigConfig, pin_factory=None, clock=None, known_faults=()) -> None:
        self.config = config
        self.clock = clock or MonotonicClock()
        self.brake_full_stroke_s = config.actuator.full_stroke_s
        self._settle_s = config.actuator.relay_settle_s
        self._lock = threading.RLock()  # the watchdog thread and signal handlers call in too
        self._depth = 0  # nesting of _held() in the thread holding the lock (> 1: a handler inside a command)
        self._pending_safe: bool | None = None  # a safe state asked for inside a command (its latch flag)
        self.faults: list[dict] = []  # wiring faults the driver found (the end switch contradicting the travel)
        pins = config.pins
        pf = dict(pin_factory=pin_factory)
        self._devices = []
        try:
            # Enable first and off: whatever happens next, the actuator has no power.
            self._enable = self._add(DigitalOutputDevice(pins.brake_enable, initial_value=False, **pf))
            self._direction = self._add(DigitalOutputDevice(pins.brake_direction, initial_value=False, **pf))
            # ``value`` True means "engine killed" whichever way the relay is wired.
            self._kill = self._add(DigitalOutputDevice(
                pins.engine_kill, active_high=(config.kill_relay == "energise_to_kill"),
                initial_value=True, **pf))
            self._reset = self._add(DigitalOutputDevice(
                pins.arduino_reset, active_high=config.reset.active_high, initial_value=False, **pf))
            th = config.throttle
            self._throttle = self._add(PWMOutputDevice(
                pins.throttle_servo, frequency=1e6 / th.frame_us,
                initial_value=th.idle_pulse_us / th.frame_us, **pf))
            # The end-of-travel switch (optional): closed to ground when fully retracted, pull-up on,
            # so a cut wire reads "not released" (the stroke's full time then decides).
            eot = getattr(pins, "brake_released_input", None)
            self._end_switch = (EndSwitch(self._add(DigitalInputDevice(eot, pull_up=True, **pf)), self.faults)
                                if eot is not None else None)
            for f in known_faults:  # found in an earlier session and not yet cleared by `dyno doctor --toggle`
                if f.get("channel") == "end_switch" and self._end_switch is not None:
                    self._end_switch.inherit(f)
        except Exception:
            self.close()
            raise
        now = self.clock.now()
        self._throttle_fraction = 0.0
        self._killed = True
        self._target = STOP  # direction asked for
        self._moving = STOP  # direction the actuator is powered in (STOP = enable off)
        self._enable_changed_s = now - 10 * self._settle_s  # pretend everything settled long ago
        self._relay_changed_s = now - 10 * self._settle_s
        self._last_integrated_s = now
        self._position = 1.0  # 0 released .. 1 full apply; unknown at start -> assume worst
        # The same travel as integrated since the brake was last known at a stop (never forced to full apply
        # as _position is after a fault): what the end switch's readings are judged against.  None: unknown.
        self._tracked: float | None = None
        self._travel = 0.0  # travel integrated since that stop, both ways (the estimate's error grows with it)
        # The position is not known (start-up; a gap in this driver's knowledge: K3 may have moved the brake,
        # see _integrate): the next release runs its full stroke by time, a closed switch never ends it, and
        # until it has run the ignition stays off (the kill chain open, K3 releasing) and no apply is taken.
        self._blind = True
        self._lost_while_running = False  # a gap came while the chain was closed: open it (see _integrate)
        self._wired_release_maybe = False  # a gap with the chain open: K3 may have released behind the estimate
        self.knowledge_lost: list[float] = []  # the times a gap made the position unknown
        self._moved_since_release = True  # a command moved the brake since the last confirmed release
        self._step_s: float | None = None  # pending timed step: duration once powered
        self._stop_at_s: float | None = None
        self._generation = 0  # bumps on every new command, so a stale step never stops a newer one
        self._latched = False
        self._safe_release = False
        # How the last safe-state release was confirmed: "end_of_travel" (the switch closed),
        # "full_stroke_time" (the stroke ran its full time + margin uninterrupted), or None (not yet /
        # interrupted: then the brake may still be on the rotor and the rig is not called safe).
        self.release_basis: str | None = None
        self.release_interrupted = ""  # why the last safe release did not complete ("" if it did or runs)
        self.refused: list[tuple[float, str, object]] = []  # (time, command, value) refused while latched
        self.last_tick_s = now
        self.closed = False
        self.safe_state()

    def _add(self, dev):
        self._devices.append(dev)
        return dev

    # ------------------------------------------------------------------ Actuators protocol

    def brake(self, direction: int) -> None:
        """Start moving (APPLY/RELEASE) until told to STOP or an end stop is reached."""
        with self._held():
            self._command(direction, None)

    def brake_step(self, direction: int, duration_s: float) -> None:
        """Non-blocking timed step: power for ``duration_s`` once the relay has settled.

        The stop happens at the first :meth:`tick` after the time is up, so
        the step is accurate to one control period; :meth:`step` is exact.
        """
        with self._held():
            self._command(direction, float(duration_s))

    def throttle(self, fraction: float) -> None:
        f = min(1.0, max(0.0, float(fraction)))
        with self._held():
            if not self.closed:
                self._catch_up(self.clock.now())
            if f > 0 and self._latched:
                self.refused.append((self.clock.now(), "throttle", f))
                raise SafetyAbort("throttle refused: safe state latched")
            self._throttle_fraction = f
            self._throttle.value = self.config.throttle.pulse_us(f) / self.config.throttle.frame_us

    def engine_kill(self, killed: bool) -> None:
        with self._held():
            if not killed and not self.closed:
                self._advance(self.clock.now())  # (a release that has just run its stroke ends the hold)
            if not killed and (self._latched or self._blind):
                self.refused.append((self.clock.now(), "engine_run", True))
                raise SafetyAbort("engine run refused: " + ("safe state latched" if self._latched else
                                                           self._blind_why()))
            self._kill.value = bool(killed)
            self._killed = bool(killed)

    def safe_state(self, latch: bool = False) -> None:
        """Throttle idle, engine killed, enable off now; release stroke follows via tick().

        ``latch=True`` (every trip: the controller's abort, the watchdog, the signal path, the E-stop)
        also refuses every later command but the release — throttle, run, and the brake in any
        direction, STOP included, since stopping a release freezes the load — until :meth:`clear_latch`.

        Called again while its release runs (a held E-stop's level check, every look), it re-asserts the
        throttle and ignition and lets that release carry on; after a confirmed release with nothing moved
        since, it starts none.  Called from a signal handler that interrupted one of this driver's own
        commands (the lock is re-entrant), it acts the moment that command returns, so no half-written
        command can follow the latch.
        """
        with self._held():
            if self._depth > 1:
                self._pending_safe = bool(latch) or bool(self._pending_safe)
                return
            self._safe_state_now(latch)

    def cut_engine_now(self) -> None:
        """Throttle idle and the kill relay open, written without the driver's lock (issue 49): the watchdog
        thread's first act, which a control loop frozen inside one of this driver's commands (holding the
        lock) must not delay.  Two pin writes, each whole on its own; :meth:`safe_state` follows under the lock."""
        if self.closed:
            return
        th = self.config.throttle
        self._throttle.value = th.idle_pulse_us / th.frame_us
        self._kill.value = True
        self._killed = True

    def _safe_state_now(self, latch: bool) -> None:
        if self.closed:
            return
        self._throttle_fraction = 0.0
        th = self.config.throttle
        self._throttle.value = th.idle_pulse_us / th.frame_us
        self._kill.value = True
        self._killed = True
        now = self.clock.now()
        self._integrate(now)
        self._latched = self._latched or latch
        running = self._safe_release and self.release_basis is None
        done = (self.release_basis is not None and not self._moved_since_release and not self._blind
                and self._target == STOP and self._moving == STOP)
        if running or done:
            return
        self._power_off(now)  # immediately, before any wait: the one non-negotiable action
        # A full stroke from wherever the estimate says, or from full apply:
        # after a fault the estimate is not trusted.
        self._position = max(self._position, 1.0)
        self.release_basis = None  # a new release to confirm
        self._safe_release = True
        self.release_interrupted = ""
        if self._end_switch is not None:
            self._end_switch.closed_seen = False
        self._generation += 1
        self._target, self._step_s, self._stop_at_s = RELEASE, None, None
        self._advance(now)

    @contextmanager
    def _held(self):
        """The lock, and a safe state asked for inside it by a signal handler applied on the way out."""
        with self._lock:
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
                if self._depth == 0 and self._pending_safe is not None:
                    latch, self._pending_safe = self._pending_safe, None
                    self._depth = 1
                    try:
                        self._safe_state_now(latch)
                    finally:
                        self._depth = 0

    def tick(self, now_s: float | None = None) -> None:
        """Called every control period; also the watchdog's sign of life.

        ``now_s`` is accepted for the protocol; the injected clock is used so
        all timing shares one time base.
        """
        with self._held():
            self.last_tick_s = self.clock.now()
            self.service()

    # ------------------------------------------------------------------ extras

    def service(self) -> None:
        """Advance time-based behaviour without counting as a control-loop tick."""
        with self._held():
            if not self.closed:
                self._advance(self.clock.now())

    def next_event_in_s(self) -> float | None:
        """Seconds (this driver's clock) until the relay/enable sequence or a stroke next changes something,
        or None: the engine services the release at these deadlines, not only on its beats."""
        with self._held():
            if self.closed:
                return None
            now = self.clock.now()
            t = self._next_event_s(now)
            return None if t is None else max(0.0, t - now)

    def clear_latch(self) -> None:
        """The explicit re-arm: commands are accepted again.  Refused (:class:`SafetyAbort`) while the
        release stroke runs or a wiring fault stands (:meth:`rearm_refusal`)."""
        with self._held():
            why = self.rearm_refusal()
            if why:
                raise SafetyAbort(f"re-arm refused: {why}")
            self._latched = False

    def _blind_why(self) -> str:
        left_s = max(0.0, self._position + END_STOP_OVERRUN_FRACTION) * self.brake_full_stroke_s
        return (f"the brake's position is unknown until its release has run the full stroke (~{left_s:.1f} s "
                "more; a closed end switch does not shorten it)")

    def close(self) -> None:
        """Drive every output to its safe value, then release the pins.

        Does not wait for a release stroke (call :meth:`finish_release` first,
        as :class:`dyno.hw.safety.SafetyGuard` does).
        """
        with self._held():
            if getattr(self, "closed", False):
                return
            if getattr(self, "_safe_release", False) and getattr(self, "release_basis", None) is None:
                self.release_interrupted = "pins released before the release stroke ended"
            for name in ("_enable", "_direction", "_reset"):
                dev = getattr(self, name, None)
                if dev is not None:
                    dev.off()
            if getattr(self, "_kill", None) is not None:
                self._kill.value = True
                self._killed = True
            if getattr(self, "_throttle", None) is not None:
                th = self.config.throttle
                self._throttle.value = th.idle_pulse_us / th.frame_us
            for dev in reversed(self._devices):
                dev.close()
            self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------------ brake state machine

    def _command(self, direction: int, duration_s: float | None) -> int:
        if direction not in (APPLY, RELEASE, STOP):
            raise ValueError(f"brake direction must be APPLY, RELEASE or STOP, got {direction!r}")
        if not self.closed:
            self._catch_up(self.clock.now())  # (a gap found now opens the chain before this command acts)
        if self._latched:
            # Nothing but the release runs while latched: STOP would freeze the brake on the rotor.
            self.refused.append((self.clock.now(), "brake", direction))
            if direction == APPLY:
                raise SafetyAbort("brake apply refused: safe state latched")
            return -1
        if self.closed:
            raise SafetyAbort("actuators closed")
        if direction == APPLY and self._blind:
            # (with K3 an apply needs the chain closed, and it stays open until the blind release has run)
            self.refused.append((self.clock.now(), "brake", direction))
            raise SafetyAbort("brake apply refused: " + self._blind_why())
        now = self.clock.now()
        self._integrate(now)
        self._generation += 1
        if direction != STOP:
            self._moved_since_release = True
            if self._end_switch is not None and direction == RELEASE:
                self._end_switch.closed_seen = False
            if direction == RELEASE and self._blind:
                self._position = max(self._position, 1.0)  # position unknown: a full stroke
        if self._safe_release and self.release_basis is None:
            self.release_interrupted = f"brake command {direction:+d} stopped the release (not latched)"
        self._safe_release = False
        self._target = direction
        self._step_s = duration_s if direction != STOP else None
        self._stop_at_s = None
        if self._moving == direction and duration_s is not None:
            self._stop_at_s = now + duration_s  # already powered this way: the step starts now
            self._step_s = None
        self._advance(now)
        return self._generation

    def _integrate(self, now: float) -> None:
        dt = now - self._last_integrated_s
        self._last_integrated_s = now
        gap = self.config.limits.supervisor_timeout_s
        if self.config.actuator.brake_hold_relay and 0 < gap < dt:
            # This driver did not run for longer than the Nano's heartbeat (a frozen Pi): the kill chain may
            # have opened meanwhile and K3 driven the brake toward its stop by wiring, behind the estimate.
            # With the chain open (this driver's kill) K3 can only have released: the estimate stays an upper
            # bound, but the switch is not judged against it until the next stop.  With it closed the position
            # is unknown: this driver opens the chain now and releases by the full stroke (_catch_up).
            self._wired_release_maybe = True
            if not self._killed:
                self._blind = True
                self._tracked = None
                self.knowledge_lost.append(now)
                self._lost_while_running = True
        if self._moving != STOP and dt > 0:
            d = self._moving * dt / self.brake_full_stroke_s
            self._position += d
            if self._tracked is not None:
                self._tracked = min(self._tracked + d, 1.0 + END_STOP_OVERRUN_FRACTION)
                self._travel += abs(d)

    def _catch_up(self, now: float) -> None:
        """Integrate to ``now``; a gap found while the chain was closed opens it and starts a full-stroke
        release (not latched: the trip is the controller's, which sees the Nano's cut)."""
        self._integrate(now)
        if self._lost_while_running:
            self._lost_while_running = False
            import logging

            logging.getLogger("dyno.outputs").error(
                "dyno: the outputs driver did not run for more than the Nano's heartbeat: the brake's position "
                "is unknown; ignition off and a full-stroke release (the chain stays open until it has run)")
            if self._depth > 1:  # inside another command (one frozen holding the lock): on its way out, as safe_state
                self._pending_safe = bool(self._pending_safe)
            else:
                self._safe_state_now(False)

    def _power_off(self, now: float) -> None:
        if self._enable.value:
            self._enable.off()
            self._enable_changed_s = now
        self._moving = STOP

    def _end_stop_reached(self, direction: int) -> bool:
        over = END_STOP_OVERRUN_FRACTION
        return (direction == APPLY and self._position >= 1.0 + over) or \
            (direction == RELEASE and self._position <= -over)

    def _advance(self, now: float) -> None:
        """Move one safe step toward the target; never relay-with-enable-on."""
        self._catch_up(now)
        if self._stop_at_s is not None and now >= self._stop_at_s - 1e-12:
            self._target, self._stop_at_s = STOP, None
        es = self._end_switch
        switch = False  # the switch (plausibly closed) and the estimate agree: at the retracted stop
        if es is not None and es.trusted and (self._blind or self._wired_release_maybe):
            # (the position unknown: a closed switch is plausible anywhere, but it neither zeroes the estimate
            # nor ends the release early: the release runs the full stroke, the closing confirming it; the
            # switch's plausibility is judged at the next apply, from the zero that stroke gives)
            if self._target == RELEASE and es.closed():
                es.closed_seen = True
        elif es is not None and es.trusted:
            if es.judge(now, self._tracked, self._travel, self.brake_full_stroke_s, self._doing()) \
                    and self._target == RELEASE:
                es.closed_seen = True
            switch = (self._target == RELEASE and es.closed_seen and self._tracked is not None
                      and self._tracked <= -tolerance(self._travel))
        if self._target != STOP and (switch or self._end_stop_reached(self._target)):
            confirmed = es is not None and es.trusted and es.closed_seen
            if self._target == RELEASE and es is not None and es.trusted and not confirmed:
                es.never_closed(now, self.brake_full_stroke_s)
            self._position = 1.0 if self._target == APPLY else 0.0  # re-zero on the stop
            self._tracked, self._travel = self._position, self._position
            self._wired_release_maybe = False
            if self._target == RELEASE:
                self._blind = False  # (a blind release started from the full-apply assumption: a full stroke)
            if self._target == RELEASE and self._safe_release:
                self.release_basis = "end_of_travel" if confirmed else "full_stroke_time"
                self._moved_since_release = False
            self._target, self._stop_at_s, self._step_s = STOP, None, None
            self._safe_release = False
        target = self._target
        if target == STOP:
            self._power_off(now)
            self._position = min(max(self._position, 0.0), 1.0 + END_STOP_OVERRUN_FRACTION)
            return
        want_relay = target == APPLY
        if bool(self._direction.value) != want_relay:
            if self._enable.value:
                self._power_off(now)
                return
            if now < self._enable_changed_s + self._settle_s:
                return
            self._direction.value = want_relay
            self._relay_changed_s = now
            return
        if not self._enable.value:
            if now < self._relay_changed_s + self._settle_s:
                return
            self._enable.on()
            self._enable_changed_s = now
            self._moving = target
            if self._step_s is not None:
                self._stop_at_s = now + self._step_s
                self._step_s = None

    def _doing(self) -> str:
        return ("while applying" if self._moving == APPLY else
                "during a release" if self._target == RELEASE else "with the actuator stopped")

    def _next_event_s(self, now: float) -> float | None:
        """Earliest time at which :meth:`_advance` would change something."""
        t = []
        if self._stop_at_s is not None:
            t.append(self._stop_at_s)
        if self._target != STOP:
            want_relay = self._target == APPLY
            if bool(self._direction.value) != want_relay:
                t.append(self._enable_changed_s + self._settle_s)
            elif not self._enable.value:
                t.append(self._relay_changed_s + self._settle_s)
            if self._moving != STOP:
                over = END_STOP_OVERRUN_FRACTION
                dist = (1.0 + over - self._position) if self._moving == APPLY else (self._position + over)
                t.append(now + max(0.0, dist) * self.brake_full_stroke_s)
                if self._end_switch is not None and self._end_switch.trusted:  # read it while moving
                    t.append(now + self._settle_s)
        t = [x for x in t if math.isfinite(x)]
        return max(now, min(t)) if t else None
