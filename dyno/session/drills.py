"""Fault drills: named, timed faults injected into the simulated rig or the host.

``--drill NAME[:ARG]@T`` (repeatable) on ``dyno run --sim``, ``dyno ui --sim`` and
``dyno calibrate --sim``; ``T`` is in simulated seconds from the run's first frame.
Each drill reproduces one fault the way it happens on the rig — in the physics,
on the bus, in the host process — and records its *physical onset* so that the
run's JSON can state the safe-state latency in true time (docs/safety.md has the
table of drills, causes and bounds).

=====================  ==================================================================
drill                  what happens at T
=====================  ==================================================================
device-reset           the Nano resets (watchdog; current bootloader restarts in ~0.1 s)
hall-dead:CH           the Hall sensor(s) give no more edges (CH: primary|secondary|both)
thermometer-stuck      the rotor thermometer repeats its last word forever
thermometer-lost       the rotor thermometer stops answering (NACK)
adc-error[:input]      the AD7171 (``:input``: the engine-side input one) sets its error bit on every conversion
adc-stuck[:input]      the AD7171 (``:input``: the input torque one) repeats one code forever
bus-lost               the I2C cable falls out: every device NACKs
overtemp               a dragging pad heats the rotor at 20 C/s while the engine runs
overspeed              the governor fails: throttle stuck wide open
loop-stall:MS          the host's event loop blocks MS milliseconds (past the liveness tolerance: engine cut)
loop-freeze[:S]        the control loop blocks S s (default 3) inside a driver call; I/O thread, watchdog run on
pi-freeze[:S]          the Pi stops entirely for S s (default 5): no polls, no watchdog thread, every output
                       pin frozen at its level (not released); the physics and the Nano run on; then the host
                       resumes (the Nano's run-enable cuts the engine: issue 37)
controller-crash       the control task raises
disk-full              the run directory refuses writes (ENOSPC)
sigint|sigterm|sighup  the process receives the signal
=====================  ==================================================================
and the wiring drills (``--mock-pins``): :mod:`dyno.session.drills_wiring`; the kill chain's: :mod:`.drills_kill`.
"""

from __future__ import annotations

import errno
import math
import os
import signal
from bisect import bisect_left
from dataclasses import dataclass

from dyno.session.drills_kill import KILL_DRILLS, KillDrills, probe_kill_windows
from dyno.session.drills_wiring import NO_TRIP_DRILLS, WIRING_DRILLS, WiringDrills, check_wiring_drill
from dyno.errors import ConfigError

OVERTEMP_RATE_C_PER_S, PI_FREEZE_DEFAULT_S = 20.0, 5.0
FREEZE_DRILLS = ("pi-freeze", "loop-freeze")  # (simulated time only; an optional S argument)

#: name -> (argument required?, allowed arguments or None, needs an engine?)
DRILLS: dict[str, tuple[bool, tuple | None, bool]] = {
    "device-reset": (False, None, False),
    "hall-dead": (True, ("primary", "secondary", "both"), True),
    "thermometer-stuck": (False, None, True),
    "thermometer-lost": (False, None, True),
    "adc-error": (False, ("input",), False),  # (an optional argument: the input torque channel's converter)
    "adc-stuck": (False, ("input",), False),
    "bus-lost": (False, None, False),
    "overtemp": (False, None, True),
    "overspeed": (False, None, True),
    "loop-stall": (True, None, False),
    "pi-freeze": (False, None, False),
    "loop-freeze": (False, None, False),
    "controller-crash": (False, None, False),
    "disk-full": (False, None, False),
    "sigint": (False, None, False),
    "sigterm": (False, None, False),
    "sighup": (False, None, False),
    **WIRING_DRILLS, **KILL_DRILLS,
}
SIGNAL_DRILLS = {"sigint": signal.SIGINT, "sigterm": signal.SIGTERM, "sighup": signal.SIGHUP}


#: ``@PHASE`` onsets: the first poll in that controller state, ``loaded`` (the pads first bite: the true
#: actuator past the brake's free travel), ``after`` (the test has ended)
PHASES = ("wait_engine", "armed", "warmup", "step", "settle", "measure", "loaded", "after")


@dataclass(frozen=True)
class Drill:
    name: str
    arg: str | None
    at_s: float  # simulated seconds from the first frame (or from the phase's start)
    phase: str | None = None  # fire at the first poll in this phase (PHASES), plus at_s

    def __str__(self) -> str:
        at = f"{self.phase}+{self.at_s:g}" if self.phase and self.at_s else (self.phase or f"{self.at_s:g}")
        return f"{self.name}{':' + self.arg if self.arg else ''}@{at}"


#: the drills that apply to the calibration fixture (no engine, no test controller, no run log)
CALIBRATION_DRILLS = ("device-reset", "adc-error", "adc-stuck", "bus-lost", "loop-stall", "sigint", "sigterm",
                      "sighup")


def parse_drill(text: str, *, engine: bool = True) -> Drill:
    """``NAME[:ARG]@T`` -> Drill; ConfigError naming ``--drill`` and what is expected.

    ``engine=False``: only the drills of the calibration fixture (:data:`CALIBRATION_DRILLS`).
    """
    names = DRILLS if engine else CALIBRATION_DRILLS
    expected = (f"NAME[:ARG]@T with NAME one of {', '.join(names)} "
                f"and T >= 0 simulated seconds from the first frame, or a phase PHASE[+S] ({', '.join(PHASES)})")
    name_arg, at, t_text = text.partition("@")
    if not at:
        raise ConfigError("command line", "--drill", f"{text!r}: missing @T; expected {expected}")
    name, _, arg = name_arg.partition(":")
    name = name.strip().lower()
    if name not in names:
        raise ConfigError("command line", "--drill", f"{text!r}: unknown drill {name!r}; expected {expected}")
    phase, _, plus = t_text.strip().lower().partition("+")
    if phase in PHASES:
        if not engine:
            raise ConfigError("command line", "--drill", f"{text!r}: phases are for test plans, not calibration")
        t_text = plus or "0"
    else:
        phase = None
    try:
        t_s = float(t_text)
    except ValueError:
        t_s = math.nan
    if not (math.isfinite(t_s) and 0.0 <= t_s <= 1e6):
        raise ConfigError("command line", "--drill", f"{text!r}: T must be a number of seconds in [0, 1e6]")
    needs_arg, allowed, _ = DRILLS[name]
    arg = arg.strip() or None
    if needs_arg and arg is None:
        what = "|".join(allowed) if allowed else {"estop-held": "SECONDS", "loop-stall": "MS"}.get(name, "ARG")
        raise ConfigError("command line", "--drill", f"{text!r}: {name} needs an argument ({name}:{what}@T)")
    if not needs_arg and arg is not None and allowed is None and name not in FREEZE_DRILLS:
        raise ConfigError("command line", "--drill", f"{text!r}: {name} takes no argument")
    if allowed is not None and arg is not None and arg not in allowed:
        raise ConfigError("command line", "--drill", f"{text!r}: argument must be one of {', '.join(allowed)}")
    numeric = {"estop-held": (3600, "estop-held:S needs 0 < S <= 3600 seconds"),
               "loop-stall": (60_000, "loop-stall:MS needs 0 < MS <= 60000"),
               "pi-freeze": (600, "pi-freeze:S needs 0 < S <= 600 seconds"),
               "loop-freeze": (600, "loop-freeze:S needs 0 < S <= 600 seconds")}
    if name in numeric and arg is not None:
        hi, why = numeric[name]
        try:
            value = float(arg)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and 0 < value <= hi):
            raise ConfigError("command line", "--drill", f"{text!r}: {why}")
    return Drill(name, arg, t_s, phase)


class DrillRunner(WiringDrills, KillDrills):
    """Arms drills on a running rig and records when each fault physically began.

    Given to the run's context at its construction (:class:`dyno.session.root.RunContext`, ``drills``; the
    calibration's too) with ``loop``, the running asyncio loop; :meth:`arm_from_first_frame` hands it that context
    (``sim``, ``controller``, ``writer``, ``poller``) when the test starts, checks the drills against it, and
    schedules them from the first accepted frame."""

    def __init__(self, drills, loop, *, sim_now=None, speed: float = 1.0) -> None:
        self.drills = list(drills)
        self.ctx = None  # the run's context, from arm_from_first_frame
        self.loop = loop
        # The UI paces the simulated rig on a real loop: sim time = (loop time - t0) x speed.
        self._sim_now = sim_now
        self.speed = float(speed or 1.0)
        self.fired: list[dict] = []  # {drill, scheduled_s, onset_s, ...} in firing order
        self.t_first_frame_s: float | None = None
        self._handles: list = []
        self._phased: list[Drill] = []  # waiting for their phase (checked on every poll)

    def _check(self, ctx) -> None:
        """A drill that cannot happen on ``ctx``'s rig must not pass as done."""
        sim = getattr(ctx, "sim", None)
        for d in self.drills:
            check_wiring_drill(d, getattr(ctx, "rig_cfg", None), getattr(ctx, "twin", None) is not None)
            if d.arg == "input" and sim is not None and not getattr(sim.model, "input_fitted", False):
                raise ConfigError("command line", "--drill", f"{d}: the rig has no input torque channel "
                                  "(rig.toml [input_torque], e.g. --rig hardware/rig-input-torque.toml)")
        from dyno.clock import VirtualTimeLoop

        frozen = next((d.name for d in self.drills if d.name in FREEZE_DRILLS), None)
        if frozen and not isinstance(self.loop, VirtualTimeLoop):
            raise ConfigError("command line", "--drill", f"{frozen} freezes the host on the simulated clock: only "
                              "in simulated time (dyno run --sim), not in a live session")

    def _in_phase(self, phase: str) -> bool:
        ctrl = getattr(self.ctx, "controller", None)
        state = getattr(getattr(ctrl, "state", None), "value", None)
        if phase == "loaded":
            sim = self.ctx.sim
            return sim is not None and not sim.model.pads_off
        if phase == "after":
            return state in ("done", "aborted")
        return state == phase

    def _on_poll(self, events, now_s: float) -> None:
        if self.t_first_frame_s is None or not self._phased:
            return
        for d in list(self._phased):
            if self._in_phase(d.phase):
                self._phased.remove(d)
                self._handles.append(self.loop.call_later(d.at_s / self.speed, self._fire, d))

    def arm_from_first_frame(self, ctx) -> DrillRunner:
        """Act on ``ctx``'s rig: the drills checked against it, scheduled from its poller's first accepted frame
        (a run and a calibration alike)."""
        self._check(ctx)
        self.ctx = ctx
        poller = ctx.poller
        if any(d.phase for d in self.drills):
            poller.listeners.append(self._on_poll)

        def first(events, now_s: float) -> None:
            if poller.last_valid_frame_s is not None:
                self.on_first_frame(poller.last_valid_frame_s)
                poller.listeners.remove(first)
        poller.listeners.append(first)
        return self

    def on_first_frame(self, now_s: float) -> None:
        if self.t_first_frame_s is not None:
            return
        self.t_first_frame_s = now_s
        sim_first = self.sim_now()
        for d in self.drills:
            if d.phase is not None:
                self._phased.append(d)
                continue
            if d.name == "device-reset":
                # The reset is a bus-level event at an exact instant: the bus applies it in time order.
                t = sim_first + d.at_s
                self.ctx.sim.bus.schedule_reset(t)
                self.fired.append({"drill": str(d), "name": d.name, "scheduled_s": t, "onset_s": t})
                continue
            self._handles.append(self.loop.call_at(now_s + d.at_s / self.speed, self._fire, d))

    def cancel(self) -> None:
        for h in self._handles:
            h.cancel()

    def sim_now(self) -> float:
        if self._sim_now is not None:
            return self._sim_now()
        return self.loop.time()

    def _fire(self, d: Drill) -> None:
        sim = self.ctx.sim
        if sim is not None:
            sim.bus.sync()  # the physics up to now: the fault acts from this instant, not the last poll
        rec = {"drill": str(d), "name": d.name, "scheduled_s": self.loop.time(), "onset_s": self.sim_now()}
        ctrl = getattr(self.ctx, "controller", None)
        if ctrl is not None:
            rec["state_at_onset"] = ctrl.state.value
        self.fired.append(rec)
        getattr(self, "_" + d.name.replace("-", "_"))(d, rec)

    # --- the faults ------------------------------------------------------------------------
    def _device_reset(self, d: Drill, rec: dict) -> None:  # (a phased one: now; timed ones go to the bus)
        self.ctx.sim.bus.schedule_reset(self.sim_now())

    def _hall_dead(self, d: Drill, rec: dict) -> None:
        chans = ("primary", "secondary") if d.arg == "both" else (d.arg,)
        self.ctx.sim.model.stuck_hall.update(chans)

    def _thermometer_stuck(self, d: Drill, rec: dict) -> None:
        self.ctx.sim.bus.thermometer_stuck = True

    def _thermometer_lost(self, d: Drill, rec: dict) -> None:
        self.ctx.sim.bus.thermometer_lost = True

    def _adc_error(self, d: Drill, rec: dict) -> None:
        if d.arg == "input":
            self.ctx.sim.model.input_error_prob = 1.0
        else:
            self.ctx.sim.model.adc_error_prob = 1.0

    def _adc_stuck(self, d: Drill, rec: dict) -> None:
        if d.arg == "input":
            self.ctx.sim.model.input_stuck = True
        else:
            self.ctx.sim.model.adc_stuck = True

    def _bus_lost(self, d: Drill, rec: dict) -> None:
        self.ctx.sim.bus.lost = True

    def _overtemp(self, d: Drill, rec: dict) -> None:
        # The physical onset is the moment the rotor crosses the limit: found from the truth trace.
        self.ctx.sim.model.extra_rotor_heat_c_per_s = OVERTEMP_RATE_C_PER_S
        rec["onset_from"] = "rotor_temp_c"

    def _overspeed(self, d: Drill, rec: dict) -> None:
        self.ctx.sim.model.governor_failed = True
        rec["onset_from"] = "rpm"

    def _loop_stall(self, d: Drill, rec: dict) -> None:
        from dyno.clock import block_loop

        block_loop(self.loop, float(d.arg) / 1000.0)

    def _pi_freeze(self, d: Drill, rec: dict) -> None:
        from dyno.session.drills_freeze import pi_freeze
        pi_freeze(self, d, rec, PI_FREEZE_DEFAULT_S)

    def _loop_freeze(self, d: Drill, rec: dict) -> None:
        from dyno.session.drills_freeze import loop_freeze
        loop_freeze(self, d, rec)

    def _controller_crash(self, d: Drill, rec: dict) -> None:
        self.ctx.controller.inject_crash(RuntimeError("drill controller-crash: the control task raised"))

    def _disk_full(self, d: Drill, rec: dict) -> None:
        self.ctx.writer.inject_disk_full()

    def _signal(self, d: Drill, rec: dict) -> None:
        os.kill(os.getpid(), SIGNAL_DRILLS[d.name])

    _sigint = _sigterm = _sighup = _signal


def enospc(path) -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def first_safe_s(history, t_from_s: float, ignore_kill=()) -> float | None:
    """First simulated instant >= ``t_from_s`` at which the physics' inputs were all safe.

    Safe: throttle idle, ignition killed, actuator not applying (stopped or releasing).
    Read from the inputs' history, so it does not matter who commanded them (the
    controller, the watchdog, a signal handler, or the real-rig output code through
    the mock pins, whose relay settle makes "release started" a little later).
    """
    from dyno.sim.rig import wired_states

    safe_before = False
    for _, t, safe in wired_states(history, ignore_kill):
        if t >= t_from_s:
            if safe_before:
                return t_from_s  # already safe when the fault began
            if safe:
                return t
        else:
            safe_before = safe
    # nothing changed after the onset: safe then (a safe state that found the outputs already safe and its
    # release done writes nothing), or never
    return t_from_s if safe_before else None


def true_latencies(ctx, aborts: list[dict], drills_from: int = 0) -> None:
    """Add true-time figures to ``aborts[0]`` of a simulated run with drills (in place).

    ``onset_s``: when the fault physically began (the drill's instant, or for
    ``overtemp``/``overspeed`` the moment the true rotor temperature / shaft speed
    crossed the limit); ``safe_commanded_s``: when the simulated outputs received
    the safe state (true time, whoever commanded it: controller, watchdog, signal
    path); ``latency_s`` = safe - onset (negative: safed before the limit was
    reached); ``detection_s``: the host's trigger time - onset.
    """
    drills = ctx.drills
    fired = drills.fired[drills_from:] if drills is not None else []
    if not aborts or not fired:
        return
    a = aborts[0]
    sim = ctx.sim
    lim = ctx.controller.limits
    truth = sim.truth
    # the fault that tripped the run: the earliest that can (a stuck end switch is found, not tripped on)
    rec = min([r for r in fired if r["name"] not in NO_TRIP_DRILLS] or fired, key=lambda r: r["onset_s"])
    onset = rec["onset_s"]
    t_from = rec["onset_s"] - 1e-9
    safe = [first_safe_s(sim.actuators.history, t_from, probe_kill_windows(ctx))]
    safe = [t for t in safe if t is not None]
    if rec.get("onset_from") == "rotor_temp_c":
        crossing = truth.crossing_s("rotor_c", lim.rotor_temp_max_c, onset)
        a["max_rotor_temp_c"] = truth.max_after("rotor_c", onset)
        a["overshoot_c"] = a["max_rotor_temp_c"] - lim.rotor_temp_max_c
        if crossing is None and safe:  # safed before the true temperature reached the limit
            crossing = _extrapolated_crossing_s(truth, "rotor_c", lim.rotor_temp_max_c, safe[0])
            a["latency_note"] = ("safe state commanded before the rotor reached the limit: onset is the "
                                 "crossing its true heating rate then would have made (negative latency)")
            a["onset_basis"] = "extrapolated"
        onset = crossing if crossing is not None else math.nan
    elif rec["name"] == "hall-dead":
        # The hazard is a silent sensor on a turning shaft: from the drill, or from when the shaft began to
        # turn if it was at rest then (a dead secondary Hall while the CVT is not yet engaged hides nothing).
        arg = rec["drill"].partition(":")[2].partition("@")[0]
        fields = ("rp", "rs") if arg == "both" else (("rp",) if arg == "primary" else ("rs",))
        starts = []
        for f in fields:
            i = bisect_left(truth.t, onset)
            if i < len(truth.t) and getattr(truth, f)[i] > HALL_TURNING_RPM:
                starts.append(onset)
            else:
                c = truth.crossing_s(f, HALL_TURNING_RPM, onset)
                if c is not None:
                    starts.append(c)
        if starts and min(starts) > onset:
            a["onset_basis"] = "the shaft began to turn"
        onset = min(starts) if starts else onset
    elif rec.get("onset_from") == "rpm":
        cands = [truth.crossing_s("rp", lim.overspeed_primary_rpm, onset),
                 truth.crossing_s("rs", lim.overspeed_secondary_rpm, onset)]
        cands = [c for c in cands if c is not None]
        onset = min(cands) if cands else math.nan
    elif rec["name"].startswith("thermometer"):
        a["max_rotor_temp_c"] = truth.max_after("rotor_c", onset)
        a["overshoot_c"] = a["max_rotor_temp_c"] - lim.rotor_temp_max_c
    a["drill"] = rec["drill"]
    a["onset_s"] = onset
    a["safe_commanded_s"] = safe[0] if safe else math.nan
    a["latency_s"] = a["safe_commanded_s"] - onset
    to_sim = getattr(ctx, "host_to_sim", None) or (lambda t: t)
    a["detection_s"] = to_sim(a["trigger_s"]) - onset if a.get("trigger_s") is not None else math.nan
    a["latency_basis"] = "true time from the physical onset (simulated rig)"
    if rec["name"] in FREEZE_DRILLS:
        from dyno.session.drills_freeze import freeze_abort_latency

        freeze_abort_latency(ctx, a, rec)


def _extrapolated_crossing_s(truth, field: str, level: float, t_s: float, span_s: float = 0.5) -> float | None:
    """When ``field`` would have crossed ``level`` had it kept its true rate of the ``span_s`` before ``t_s``."""
    from bisect import bisect_left

    t, a = truth.t, getattr(truth, field)
    j = min(bisect_left(t, t_s), len(t) - 1)
    i = bisect_left(t, t_s - span_s)
    if j <= i:
        return None
    rate = (a[j] - a[i]) / (t[j] - t[i])
    if not rate > 0:
        return None
    return t[j] + (level - a[j]) / rate


def _truth_range(truth, field: str, t0_s: float, t1_s: float) -> tuple[float, float]:
    from bisect import bisect_left, bisect_right

    i, j = bisect_left(truth.t, t0_s), bisect_right(truth.t, t1_s)
    vals = getattr(truth, field)[i:j]
    return (min(vals), max(vals)) if len(vals) else (math.nan, math.nan)


#: a shaft turning slower than this has no edges to miss: a silent Hall sensor reads what it should
HALL_TURNING_RPM = 100.0
#: a thermometer repeating one word hides nothing while the true temperature moves less than this
THERMO_MOVING_C = 1.0


def hazard_verdicts(ctx, drills_from: int = 0) -> None:
    """Add ``hazard_arose`` (and, when false, ``hazard_note``: why) to every fired drill (in place).

    The hazard is the physical one the drill targets, read from the simulated world's truth: a limit
    crossed, a sensor silent while what it measures changes, the bus gone, the loop silent past the
    watchdog.  The window is from the onset to the first safe state after it (or the end of the run).
    """
    drills = getattr(ctx, "drills", None)
    sim = getattr(ctx, "sim", None)
    if drills is None or sim is None or not hasattr(sim, "truth"):
        return
    truth = sim.truth
    ctrl = ctx.controller
    lim = ctrl.limits
    end_s = sim.model.t_s
    for rec in drills.fired[drills_from:]:
        t0 = rec["onset_s"]
        t_safe = first_safe_s(sim.actuators.history, t0 - 1e-9, probe_kill_windows(ctx))
        t1 = t_safe if t_safe is not None and t_safe > t0 else end_s
        name, arg = rec["name"], rec["drill"].partition(":")[2].partition("@")[0]
        arose, note = True, ""
        if name == "overtemp":
            lo, hi = _truth_range(truth, "rotor_c", t0, end_s)
            arose = truth.crossing_s("rotor_c", lim.rotor_temp_max_c, t0) is not None or hi > lim.rotor_temp_max_c
            note = (f"the rotor's true temperature peaked at {hi:.2f} C, below the {lim.rotor_temp_max_c:g} C "
                    "limit: the engine stopped driving it (safe state or end of test) first")
        elif name == "overspeed":
            _, rp = _truth_range(truth, "rp", t0, end_s)
            _, rs = _truth_range(truth, "rs", t0, end_s)
            arose = rp > lim.overspeed_primary_rpm or rs > lim.overspeed_secondary_rpm
            note = (f"throttle stuck open, but the true speeds peaked at {rp:.0f} rpm primary / {rs:.0f} rpm "
                    f"secondary, below the {lim.overspeed_primary_rpm:g} / {lim.overspeed_secondary_rpm:g} rpm "
                    "limits (the brake's load held them, or the engine was not running)")
        elif name == "hall-dead":
            chans = ("rp", "rs") if arg == "both" else (("rp",) if arg == "primary" else ("rs",))
            peak = max(_truth_range(truth, c, t0, t1)[1] for c in chans)
            arose = peak > HALL_TURNING_RPM
            note = (f"the {arg} shaft{'s' if arg == 'both' else ''} turned at most {peak:.0f} rpm from the onset "
                    "to the safe state: a silent sensor read what it should")
        elif name == "thermometer-stuck":
            lo, hi = _truth_range(truth, "rotor_c", t0, t1)
            arose = hi - lo >= THERMO_MOVING_C
            note = (f"the rotor's true temperature moved {hi - lo:.2f} C while the thermometer repeated itself: "
                    "the stuck word was still the truth")
        elif name == "loop-stall":
            from dyno.session.drills_freeze import stall_verdict

            arose, note = stall_verdict(ctx, float(arg) / 1000.0)
        elif name == "controller-crash":
            arose = rec.get("state_at_onset") not in ("done", "aborted")
            note = f"the control task had already ended ({rec.get('state_at_onset')}): nothing left to crash"
        elif name == "disk-full":
            arose = getattr(ctx.writer, "error", None) is not None
            note = "no write was attempted after the disk filled"
        elif name in WIRING_DRILLS or name in KILL_DRILLS:
            arose, note = drills._wiring_verdict(rec, name) if name in WIRING_DRILLS else drills._kill_verdict(rec)
        elif name in FREEZE_DRILLS:
            from dyno.session.drills_freeze import freeze_verdict

            freeze_verdict(ctx, rec)
            continue
        rec["hazard_arose"] = bool(arose)
        if not arose:
            rec["hazard_note"] = note
