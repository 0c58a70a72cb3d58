"""The closed-loop law of a brake hold (pure: no I/O, time passed in).

The brake's linear actuator *integrates* its command (it moves at a fixed speed while powered), so the
command is the actuator's velocity ``u`` in [-1, 1] of full speed, and a proportional law on the error is
already integral action on the brake's position::

    e = s (x - x_set) / x_set                    relative error (s = +1: more brake lowers x)
    u = kp (e + lead_s de/dt) + ki ∫ e dt        clipped to [-1, 1]

The ``kp`` part moves the brake while the error lasts (a constant load is held with zero error, no ``ki``
needed); the ``lead_s`` part sets the brake's position in proportion to the error (a PI on position),
which damps a plant whose speed answers the brake slowly.  The dead band is judged on the error one lead
ahead, ``e + lead_s de/dt``, so a correction under way is not doubled while the plant's lag hides it.
Anti-windup: the integral is frozen while ``u`` is saturated in the error's direction.

``u`` becomes at most one actuator pulse per period ``T`` (:meth:`HoldLaw.pulse`): sigma-delta, the
travel asked for, ``Σ u T``, accumulates until it is worth a pulse of at least ``min_pulse_s``.  Near
the setpoint after a reversal (the last correction crossed the whole dead band: the CVT's sheaves stick
in their shift friction, :mod:`dyno.sim.cvt_friction`) the minimum pulse is ``fine_pulse_s``.  The gains'
tuning and its figures: docs/control.md, docs/measurements/2026-11-29-hold-friction.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from dyno.control.outputs import APPLY, RELEASE, STOP


@dataclass(frozen=True)
class HoldGains:
    """The law's settings (module doc).  ``rig.toml``'s ``[control]`` gives the rig's (:meth:`from_config`);
    the defaults are tuned on the simulated rig through the real output code (``bench/bench_test_time.py``,
    ``bench/bench_hold_tune.py``): ``kp`` 12 with a 0.5 s lead settles 5 % steps of the secondary within
    ±0.5 % in ≤ 1.5 s."""

    kp: float = 12.0  # actuator speed fraction per unit relative speed error
    ki_per_s: float = 0.0
    period_s: float = 0.05  # one pulse decision per period
    deadband_rel: float = 0.004  # |e| below this: no pulse (relay wear, hunting)
    min_pulse_s: float = 0.02
    speed_window_s: float = 0.15
    ff_s: float = 0.0  # feed-forward: full-speed travel (s) per unit relative setpoint change
    lead_s: float = 0.5  # the position term's lead (the plant's lag); 0: the actuator's speed alone
    derivative_window_s: float = 0.1  # the error's rate over this span (two periods)
    # Near the setpoint after a reversal the minimum pulse is shorter (the CVT's stuck sheaves, above); 0: off
    fine_pulse_s: float = 0.01
    fine_band_rel: float = 0.01  # "near": |error one lead ahead| below this

    @classmethod
    def from_config(cls, control, variable: str = "secondary") -> "HoldGains":
        """The gains ``rig.toml``'s ``[control]`` gives for ``variable`` (secondary | engine | torque)."""
        kp = {"secondary": control.kp_speed, "engine": control.kp_engine, "torque": control.kp_torque}[variable]
        lead = {"secondary": control.lead_speed_s, "engine": control.lead_engine_s, "torque": 0.0}[variable]
        return cls(kp=kp, period_s=control.period_s, deadband_rel=control.deadband_rel,
                   min_pulse_s=control.min_pulse_s, ff_s=control.ff_speed_s if variable == "secondary" else 0.0,
                   speed_window_s=0.2 if variable == "torque" else cls.speed_window_s, lead_s=lead)


class HoldLaw:
    """The law above (pure: no I/O, time passed in)."""

    def __init__(self, gains: HoldGains = HoldGains()) -> None:
        self.g = gains
        self.reset()

    def reset(self) -> None:
        self.integral = 0.0
        self.owed_s = 0.0  # actuator travel asked for but not yet given (s at full speed)
        self.e_hist: list[float] = []  # the last errors, one a period (the rate over derivative_window_s)
        self.e_lead = math.nan  # e + lead·de/dt: where the error is heading
        self.last_dir = 0  # the last pulse's direction (+1 apply, -1 release, 0 none yet)
        self.fine = False  # near the setpoint after a reversal there: the minimum pulse is ``fine_pulse_s``

    def update(self, rpm: float, setpoint_rpm: float, dt_s: float) -> float:
        """Actuator command in [-1, 1] (+: apply more brake) for the measured ``rpm``."""
        if not (rpm > 0 and setpoint_rpm > 0):
            return 0.0
        return self.command((rpm - setpoint_rpm) / setpoint_rpm, dt_s)

    def feed_forward(self, old_setpoint: float, new_setpoint: float, sign: float = -1.0) -> None:
        """A setpoint change: owe the travel the plant's gain says it needs at once (``ff_s`` per unit
        relative change; ``sign`` -1 for speeds: a lower speed needs more brake; +1 for torque)."""
        if self.g.ff_s > 0 and old_setpoint > 0 and new_setpoint > 0:
            self.owed_s += sign * self.g.ff_s * (new_setpoint - old_setpoint) / old_setpoint

    def command(self, e: float, dt_s: float) -> float:
        """Actuator command in [-1, 1] for the relative error ``e`` (+: apply more brake)."""
        if not math.isfinite(e):
            return 0.0
        u = self.g.kp * e + self.g.ki_per_s * self.integral
        if self.g.lead_s and dt_s > 0:
            n = max(1, round(self.g.derivative_window_s / dt_s))
            self.e_hist.append(e)
            del self.e_hist[:-(n + 1)]
            rate = (e - self.e_hist[0]) / (dt_s * (len(self.e_hist) - 1)) if len(self.e_hist) > 1 else 0.0
            self.e_lead = e + self.g.lead_s * rate
            u += self.g.kp * self.g.lead_s * rate
        saturated = abs(u) >= 1.0 and math.copysign(1.0, u) == math.copysign(1.0, e)
        if self.g.ki_per_s and not saturated:  # anti-windup: no integration into a saturated command
            self.integral += e * dt_s
        return max(-1.0, min(1.0, u))

    def pulse(self, u: float, e_rel: float) -> tuple[int, float]:
        """(direction, on-time in s) for command ``u`` over one period.

        Sigma-delta: the travel asked for accumulates until it is worth a pulse of at
        least ``min_pulse_s``, so a small command still moves the brake (slowly) instead
        of being lost under the minimum pulse.

        Inside the dead band nothing moves, but the travel already owed is kept while the error stays on
        the same side (dropped when it changes side: the ask is stale), so an exit from the band does not
        start from zero while the brake's fade carries the speed away (docs/control.md, "Resolution and drift").
        """
        if not math.isfinite(e_rel):
            self.owed_s = 0.0
            return STOP, 0.0
        if self.owed_s * u < 0:
            self.owed_s = 0.0
        e_band = self.e_lead if self.g.lead_s and math.isfinite(self.e_lead) else e_rel
        if abs(e_band) < self.g.deadband_rel:  # (with a lead: the error one lag ahead, where it is heading)
            return STOP, 0.0
        self.owed_s += u * self.g.period_s
        min_pulse_s = self.g.min_pulse_s
        if 0 < self.g.fine_pulse_s < min_pulse_s and abs(e_band) < self.g.fine_band_rel:
            # a reversal near the setpoint: the last correction crossed the whole dead band (one minimum pulse
            # is more than the band: the CVT's sheaves stuck in its shift friction), so go finer from here
            self.fine = self.fine or (self.last_dir * self.owed_s < 0)
            if self.fine:
                min_pulse_s = self.g.fine_pulse_s
        else:
            self.fine = False
        if abs(self.owed_s) < min_pulse_s:
            return STOP, 0.0
        on_s = min(abs(self.owed_s), self.g.period_s)
        direction = APPLY if self.owed_s > 0 else RELEASE
        self.owed_s -= math.copysign(on_s, self.owed_s)
        self.last_dir = 1 if direction == APPLY else -1
        return direction, on_s
