"""The blocking helpers of :class:`dyno.hw.outputs.GpioActuators`: a timed step, waiting out a release, the
Nano's reset pulse.  For exit paths, ``dyno doctor`` and tests on a fake clock; the control loop never calls
them (it drives time through ``tick``).  A mixin: these use the driver's lock and state machine.
"""

from __future__ import annotations

from dyno.control.outputs import STOP


class BlockingMixin:
    def step(self, direction: int, duration_s: float) -> None:
        """Blocking timed step: the enable is on for exactly ``duration_s``.

        If anything interrupts it (exception, signal) the enable is switched off
        on the way out, unless a newer command (e.g. the safe state) owns it.
        """
        with self._held():
            gen = self._command(direction, float(duration_s))
        if gen < 0:  # refused (latched): the release owns the actuator
            return
        try:
            while True:
                with self._held():
                    if self._generation != gen or self.closed:
                        return
                    now = self.clock.now()
                    self.last_tick_s = now  # this loop is the control loop while it runs
                    self._advance(now)
                    if self._moving == STOP and self._target == STOP:
                        return
                    wait = self._next_event_s(now)
                self.clock.sleep(min(max(0.0, wait - now) if wait is not None else self._settle_s, self._slice_s()))
        finally:
            with self._held():
                if self._generation == gen and not self.closed:
                    self._command(STOP, None)

    def finish_release(self, timeout_s: float | None = None) -> bool:
        """Block until the brake is released and de-energised (exit paths)."""
        limit = timeout_s if timeout_s is not None else 2 * self.brake_full_stroke_s + 10 * self._settle_s + 1
        t_end = self.clock.now() + limit
        while True:
            with self._held():
                if self.closed:
                    return False
                now = self.clock.now()
                self.last_tick_s = now  # servicing the release: the control loop is alive
                self._advance(now)
                if self.released:
                    return True
                if now >= t_end:
                    self._power_off(now)
                    return False
                wait = self._next_event_s(now)
            step = (wait - now) if wait is not None else self._settle_s
            self.clock.sleep(min(max(step, 1e-3), max(t_end - now, 1e-3), self._slice_s()))

    def _slice_s(self) -> float:
        """The longest sleep here: half the Nano's heartbeat, so a helper's own wait is never taken for a gap in
        the driver's knowledge (:meth:`dyno.hw.outputs.GpioActuators._integrate`)."""
        gap = self.config.limits.supervisor_timeout_s
        return 0.5 * gap if gap > 0 else float("inf")

    def reset_arduino(self) -> None:
        """Pulse the Nano's RESET, then wait for its bootloader to hand over (blocking).

        The wait (1.25 s with the shipped [reset]) is longer than the watchdog's timeout: like :meth:`step`,
        this loop is the control loop while it runs, so it services the outputs and beats as it waits.
        """
        r = self.config.reset
        with self._held():
            self._reset.on()
        try:
            self._wait_alive(r.pulse_s)
        finally:
            with self._held():
                self._reset.off()
        self._wait_alive(r.boot_s)

    def _wait_alive(self, seconds: float, slice_s: float = 0.05) -> None:
        end = self.clock.now() + seconds
        while True:
            with self._held():
                now = self.clock.now()
                self.last_tick_s = now
                if not self.closed:
                    self._advance(now)
            if now >= end:
                return
            self.clock.sleep(min(slice_s, end - now))
