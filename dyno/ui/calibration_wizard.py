"""The known-weights torque calibration as a pure state machine (no Textual, no I/O).

Procedure (Messick 2018, Section 9.2): lock the secondary, wrap a rope on the
brake rotor at a measured radius, hang masses in steps.  The torque at the
secondary is ``m g r * 32/61`` (:func:`dyno.analysis.calibration.torque_from_mass`).

::

    SETUP --start()--> TARE_BEFORE --> LOADING (ascending) --> UNLOADING (descending)
          --> TARE_AFTER --> REVIEW --accept()--> ACCEPTED
                                    \\--reject()--> REJECTED

Each step: the operator confirms the load is hanging still (:meth:`begin_step`),
then ADC samples arrive (:meth:`add_samples`); the first ``settle_samples`` are
dropped (the rope still swinging, the lock-in filter settling), then
``n_samples`` are kept.  Conversions with the AD7171 error bit or at a rail
are refused and counted, never averaged, as in a test point.

The engine-side input channel (issue 27, ``channel="input"``) is calibrated
the same way with the engine off and its cradle free: masses on the cradle's
arm at a measured length ``L``, ``T = m g L`` of crank torque (no gear).

``repeats`` applies the whole load sequence (loading, then unloading) that
many times between the two tares: the line is fitted through every step
(:func:`dyno.analysis.calibration.fit_repeats`, on the raw samples per step,
so its standard errors come from the step-to-step scatter), each repeat on
its own too, and the spread of the repeats' slopes is the calibration's
reproducibility — shown against the 0.4 % that brings the map-free
efficiency's U95 to about 2 pp (``REPRODUCIBILITY_TARGET_REL``).  The tare
readings are a drift check, not part of the line.
Nothing is written unless :meth:`accept` is called with a fit that passed
every check, and then through the atomic :func:`append_entry`.  The poller
listener that feeds it and a whole simulated session are in
:mod:`dyno.ui.calibration_feed`.
"""

from __future__ import annotations

import datetime as _dt
import enum
import math
from dataclasses import dataclass, field

import numpy as np

from dyno.analysis.calibration_history import (G_STANDARD_M_PER_S2, GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY,
                                               R2_MIN_DEFAULT, CalibrationRejected, append_entry)
from dyno.analysis.calibration import REPRODUCIBILITY_TARGET_REL, check_loads, fit_repeats, torque_from_mass

ADC_STATUS_ERR = 0x20
ADC_RAILS = (0, 0xFFFF)
CHANNELS = ("output", "input")  # the brake-side torque channel; the engine-side one (issue 27)
MAX_REPEATS = 20
# The zero drift refuses only beyond this many standard errors (a 3-sigma event is 1 in 370 by noise).
DRIFT_SIGNIFICANCE = 3.0


class Phase(enum.Enum):
    SETUP = "setup"
    TARE_BEFORE = "tare_before"
    LOADING = "loading"
    UNLOADING = "unloading"
    TARE_AFTER = "tare_after"
    REVIEW = "review"
    ACCEPTED = "accepted"
    REJECTED = "rejected"


COLLECTING_PHASES = (Phase.TARE_BEFORE, Phase.LOADING, Phase.UNLOADING, Phase.TARE_AFTER)


@dataclass
class Step:
    """One load step: the plan, then the samples and their statistics."""

    phase: Phase
    mass_kg: float
    torque_nm: float
    direction: int  # +1 loading, -1 unloading, 0 tare
    repeat: int = 0  # which pass of the load sequence (0-based; tares 0)
    from_zero: bool = False  # a repeat's first load: every mass off first, so it is approached from below
    samples: list = field(default_factory=list)
    dropped_settling: int = 0
    refused: int = 0  # error bit or rail

    @property
    def n(self) -> int:
        return len(self.samples)

    @property
    def mean_counts(self) -> float:
        return float(np.mean(self.samples)) if self.samples else math.nan

    @property
    def std_counts(self) -> float:
        return float(np.std(self.samples, ddof=1)) if len(self.samples) > 1 else math.nan

    @property
    def sem_counts(self) -> float:
        return self.std_counts / math.sqrt(self.n) if self.n > 1 else math.nan


def parse_masses(text: str) -> list[float]:
    """'5, 10 20' -> [5.0, 10.0, 20.0]; raises ValueError naming the bad item."""
    out = []
    for item in text.replace(",", " ").split():
        try:
            out.append(float(item))
        except ValueError:
            raise ValueError(f"mass {item!r} is not a number (kg)") from None
    return out


class CalibrationWizard:
    """State and validation of one calibration session.

    Parameters
    ----------
    n_samples : int
        ADC samples kept per step (default 500, about 4 s at 125 Hz).
    settle_samples : int
        Samples dropped at the start of each step (default 125, about 1 s).
    r2_min : float
        Refuse a fit below this R^2.
    zero_drift_max_nm : float
        Refuse when the tare after differs from the tare before by more than
        this (in secondary torque, with the new slope) *and* by more than
        ``DRIFT_SIGNIFICANCE`` standard errors of that difference: the bridge
        drifted or the rope did not come off.  The second condition matters
        only for short tares: with ``n`` samples of scatter ``s`` the
        difference of two tare means scatters by ``s sqrt(2/n)`` (0.11 N·m for
        100 samples on the thesis bridge, 0.05 N·m for the default 500), so a
        bare threshold at 0.25 N·m refused one short calibration in ~40 for
        noise alone.  When the tares are too short to resolve the limit the
        review says so (:meth:`zero_check_inconclusive`).
    previous : CalibrationEntry, optional
        The calibration in force: the tare before is compared with its intercept.
    channel : "output" or "input"
        The brake-side channel (torque at the secondary through the 32:61 gear) or the engine-side one
        (crank torque on the cradle's arm: gear ratio 1).
    repeats : int
        Passes of the load sequence (loading and unloading) between the tares; from 2 on, the slope's
        reproducibility across them is shown.
    history : list of CalibrationEntry, optional
        The channel's history so far: the review shows the calibration term it will give with this
        entry appended (:func:`dyno.analysis.systematic.calibration_rel_u`).
    """

    def __init__(self, *, n_samples: int = 500, settle_samples: int = 125, r2_min: float = R2_MIN_DEFAULT,
                 min_distinct_loads: int = 3, zero_drift_max_nm: float = 0.25,
                 gear_ratio_brake_per_secondary: float = GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY,
                 g_m_per_s2: float = G_STANDARD_M_PER_S2, previous=None, channel: str = "output",
                 repeats: int = 1, history=None) -> None:
        if n_samples < 2:
            raise ValueError("n_samples must be >= 2")
        if channel not in CHANNELS:
            raise ValueError(f"channel must be one of {CHANNELS}, got {channel!r}")
        if not 1 <= int(repeats) <= MAX_REPEATS:
            raise ValueError(f"repeats must be 1..{MAX_REPEATS}")
        self.channel = channel
        self.repeats = int(repeats)
        self.history = list(history or [])
        self.repro = None  # dyno.analysis.calibration.Reproducibility after the fit
        if channel == "input":
            gear_ratio_brake_per_secondary = 1.0  # the loads hang on the cradle's own arm: crank torque
        self.n_samples = int(n_samples)
        self.settle_samples = int(settle_samples)
        self.r2_min = r2_min
        self.min_distinct_loads = min_distinct_loads
        self.zero_drift_max_nm = zero_drift_max_nm
        self.gear_ratio = gear_ratio_brake_per_secondary
        self.g_m_per_s2 = g_m_per_s2
        self.previous = previous
        self.phase = Phase.SETUP
        self.radius_m: float | None = None
        self.masses_kg: list[float] = []
        self.steps: list[Step] = []
        self.index = 0  # current step
        self.collecting = False
        self.fit = None
        self.rejection: str | None = None
        self.entry = None
        self.step_error: str | None = None  # why the current step stopped without completing
        self.generation = 0  # +1 at every begin_step / redo_step (the feeder's cue to catch up first)

    # --- setup --------------------------------------------------------------------------
    aborted: tuple[str, str] | None = None  # (cause, detail) once a fault ended the calibration

    def configure(self, radius_m: float, masses_kg) -> list[str]:
        """Set the rope radius and the masses; returns the problems ([] = ready to start)."""
        problems = []
        try:
            radius_m = float(radius_m)
        except (TypeError, ValueError):
            radius_m = math.nan
        if not (math.isfinite(radius_m) and 0.01 <= radius_m <= 1.0):
            what = "arm length" if self.channel == "input" else "rope radius"
            problems.append(f"{what} must be between 0.01 and 1 m, got {radius_m}")
        masses = [float(m) for m in masses_kg]
        problems += check_loads(masses, min_distinct=self.min_distinct_loads)
        if not problems:
            self.radius_m = radius_m
            self.masses_kg = sorted(masses)
            self._plan()
        return problems

    def _torque(self, mass_kg: float) -> float:
        if mass_kg == 0:
            return 0.0
        return float(torque_from_mass(mass_kg, self.radius_m, self.gear_ratio, self.g_m_per_s2))

    def _plan(self) -> None:
        up = self.masses_kg
        # Unloading revisits every load below the top one: the pairs give the hysteresis.
        down = list(reversed(up[:-1]))
        self.steps = [Step(Phase.TARE_BEFORE, 0.0, 0.0, 0)]
        for k in range(self.repeats):  # each repeat: the whole sequence again, loading then unloading
            # From the second repeat on, its first load follows the unloading's last step at the same load:
            # every mass comes off first, or that "loading" step would be the unloading's state again
            # (the friction in a cradle's bearings then reads +b there, not -b).
            self.steps += ([Step(Phase.LOADING, m, self._torque(m), +1, k, from_zero=k > 0 and i == 0)
                            for i, m in enumerate(up)]
                           + [Step(Phase.UNLOADING, m, self._torque(m), -1, k) for m in down])
        self.steps.append(Step(Phase.TARE_AFTER, 0.0, 0.0, 0))

    def start(self) -> None:
        if not self.steps:
            raise RuntimeError("configure() the radius and masses first")
        self.index = 0
        self.phase = self.steps[0].phase

    # --- steps ----------------------------------------------------------------------------
    @property
    def current(self) -> Step | None:
        return self.steps[self.index] if self.phase in COLLECTING_PHASES else None

    def instruction(self) -> str:
        """What the operator should do now."""
        s = self.current
        inp = self.channel == "input"
        if self.phase is Phase.SETUP:
            return ("Enter the cradle arm's length and the masses, then start." if inp
                    else "Enter the rope radius and the masses, then start.")
        if s is not None:
            where = f"step {self.index + 1}/{len(self.steps)}"
            if s.direction == 0:
                which = "before" if s.phase is Phase.TARE_BEFORE else "after"
                if inp:
                    todo = ("Engine OFF, cradle free, NO mass on the arm" if which == "before"
                            else "Take ALL masses off the arm")
                else:
                    todo = ("Lock the secondary. Rope slack, NO mass hanging" if which == "before"
                            else "Take ALL masses and the rope off")
                return f"{where}: zero check {which}. {todo}; then collect."
            verb = "Add masses to" if s.direction > 0 else "Remove masses down to"
            if s.from_zero:
                verb = "Take ALL masses off, then hang"
            rep = f", repeat {s.repeat + 1}/{self.repeats}" if self.repeats > 1 else ""
            at = "crank torque on the cradle" if inp else "at the secondary"
            return (f"{where} ({s.phase.value}{rep}): {verb} a total of {s.mass_kg:g} kg "
                    f"(T = {s.torque_nm:.2f} N·m {at}); wait until it hangs still, then collect.")
        if self.phase is Phase.REVIEW:
            return "Review the fit: accept to append it to the history, or reject."
        if self.phase is Phase.ACCEPTED:
            return "Accepted and appended to the calibration history."
        return f"Not accepted: {self.rejection}"

    def begin_step(self) -> Step:
        """The operator says the load is in place and still: start collecting."""
        s = self.current
        if s is None:
            raise RuntimeError(f"nothing to collect in phase {self.phase.value}")
        s.samples.clear()
        s.dropped_settling = s.refused = 0
        self.step_error = None
        self.collecting = True
        self.generation += 1
        return s

    def add_samples(self, codes, statuses=None) -> bool:
        """Feed ADC conversions; returns True when the current step is complete."""
        if not self.collecting:
            return False
        s = self.current
        statuses = statuses if statuses is not None else [0] * len(codes)
        for code, status in zip(codes, statuses):
            if s.dropped_settling < self.settle_samples:
                s.dropped_settling += 1
                continue
            if status & ADC_STATUS_ERR or code in ADC_RAILS:
                s.refused += 1
                if s.refused > 2 * self.n_samples:
                    # An overloaded bridge sits at the rail for ever: stop and say so
                    # rather than collect until the operator gives up.
                    self.collecting = False
                    self.step_error = (f"{s.refused} conversions refused (AD7171 error bit or at a rail): "
                                       f"the load overloads the ADC or the bridge is disconnected")
                    return True
                continue
            s.samples.append(float(code))
            if s.n >= self.n_samples:
                self.collecting = False
                self._advance()
                return True
        return False

    @property
    def progress(self) -> float:
        """0..1 of the current step (settling counts as the first part)."""
        s = self.current
        if s is None:
            return 0.0 if self.phase is Phase.SETUP else 1.0
        total = self.settle_samples + self.n_samples
        return min(1.0, (s.dropped_settling + s.n) / total)

    def redo_step(self) -> None:
        """Discard the current step's samples (e.g. someone bumped the rope)."""
        s = self.current
        if s is not None:
            s.samples.clear()
            s.dropped_settling = s.refused = 0
            self.collecting = False
            self.generation += 1

    def _advance(self) -> None:
        self.index += 1
        if self.index < len(self.steps):
            self.phase = self.steps[self.index].phase
        else:
            self.phase = Phase.REVIEW
            self._fit()

    # --- checks and fit -----------------------------------------------------------------------
    @property
    def tare_before(self) -> Step:
        return self.steps[0]

    @property
    def tare_after(self) -> Step:
        return self.steps[-1]

    def load_steps(self) -> list[Step]:
        return [s for s in self.steps if s.direction != 0]

    def zero_drift_counts(self) -> float:
        if not self.steps:
            return math.nan
        return self.tare_after.mean_counts - self.tare_before.mean_counts

    def zero_drift_se_counts(self) -> float:
        """Standard error of :meth:`zero_drift_counts` from the two tares' scatter.

        ``se = sqrt(s_b^2 / n_b + s_a^2 / n_a)``, white noise assumed: noise
        correlated from sample to sample makes this smaller than the truth,
        which errs towards refusing.
        """
        if not self.steps:
            return math.nan
        return math.hypot(self.tare_before.sem_counts, self.tare_after.sem_counts)

    def zero_check_inconclusive(self) -> bool:
        """The tares are too short to tell a drift at the limit from their noise."""
        if self.fit is None:
            return False
        se_nm = self.zero_drift_se_counts() / abs(self.fit.slope_counts_per_nm)
        return not DRIFT_SIGNIFICANCE * se_nm <= self.zero_drift_max_nm

    def previous_zero_offset_nm(self) -> float | None:
        """The tare before against the calibration in force, in N·m (None without one)."""
        if self.previous is None or not self.steps or not self.tare_before.n:
            return None
        return float(self.previous.torque_secondary_nm(self.tare_before.mean_counts))

    def _fit(self) -> None:
        steps = self.load_steps()
        try:
            self.fit, self.repro = fit_repeats([s.torque_nm for s in steps], [np.asarray(s.samples) for s in steps],
                                               [s.repeat for s in steps], direction=[s.direction for s in steps],
                                               r2_min=self.r2_min, min_distinct_loads=self.min_distinct_loads,
                                               # the cradle's bearings: the line between the two branches
                                               friction_term=self.channel == "input")
        except CalibrationRejected as exc:
            self.fit = self.repro = None
            self.rejection = str(exc)
            return
        drift_nm = self.zero_drift_counts() / self.fit.slope_counts_per_nm
        se_nm = self.zero_drift_se_counts() / abs(self.fit.slope_counts_per_nm)
        # A NaN s.e. (a tare of one sample) cannot excuse anything: "not <=" refuses then.
        if abs(drift_nm) > self.zero_drift_max_nm and not abs(drift_nm) <= DRIFT_SIGNIFICANCE * se_nm:
            self.rejection = (f"zero drifted by {drift_nm:+.3f} ± {se_nm:.3f} N·m between the tare before and "
                              f"after (limit {self.zero_drift_max_nm} N·m): bridge drift, a rope left on, or the "
                              f"secondary lock slipped; repeat the calibration")
        else:
            self.rejection = None

    @property
    def acceptable(self) -> bool:
        return self.phase is Phase.REVIEW and self.fit is not None and self.rejection is None

    def result_lines(self) -> list[str]:
        """The fit summary for the screen (plain text)."""
        f = self.fit
        lines = []
        if f is not None:
            drift = self.zero_drift_counts()
            lines += [f"slope  {f.slope_counts_per_nm:.3f} ± {f.slope_se_counts_per_nm:.3f} counts/N·m",
                      f"icpt   {f.intercept_counts:.1f} ± {f.intercept_se_counts:.1f} counts",
                      f"R²     {f.r2:.6f} (min {self.r2_min})",
                      f"non-lin {f.nonlinearity_pct_fs:.3f} %FS"
                      + (f"  hyst {f.hysteresis_pct_fs:.3f} %FS" if f.hysteresis_pct_fs is not None else ""),
                      # N·m only (the tares' counts are in the table): the line fits the 80-column review
                      f"zero drift {drift / f.slope_counts_per_nm:+.3f} "
                      f"± {self.zero_drift_se_counts() / abs(f.slope_counts_per_nm):.3f} N·m"]
            if self.zero_check_inconclusive():
                lines.append(f"zero check inconclusive: tares too short for {self.zero_drift_max_nm} N·m")
            if f.friction_nm is not None:  # the input channel: half the hysteresis, rig.toml bearing_loss_nm
                lines.append(f"cradle friction {f.friction_nm:+.3f} ± {f.friction_se_counts / f.slope_counts_per_nm:.3f} N·m")
            lines += self.reproducibility_lines()
        prev = self.previous_zero_offset_nm()
        if prev is not None:
            lines.append(f"tare vs cal. in force {prev:+.3f} N·m")
        if self.rejection:
            lines.append(f"REFUSED: {self.rejection}")
        return lines

    def reproducibility_lines(self) -> list[str]:
        """The slope's spread across the repeats against the target, and the history's term after this."""
        r, target = self.repro, REPRODUCIBILITY_TARGET_REL
        if r is None:
            return []
        if r.n < 2:
            out = ["reproducibility: 1 repeat (--repeats 3)"]
        else:
            out = [f"reproducibility {100 * r.rel_sd:.2f} % ({r.n} repeats)",
                   f"  {'meets' if r.meets(target) else 'ABOVE'} the {100 * target:.1f} % for U95 <= 2 pp"]
        term = self.history_term()
        if term is not None and term[1] >= 2:  # the term the runs will use: the history's spread
            out.append(f"history term {100 * term[0]:.2f} % ({term[1]} entries)")
        elif term is not None:
            out.append("history: 1 entry, no spread yet")
        return out

    def history_term(self) -> tuple[float, int] | None:
        """The channel's calibration term (relative) with this fit appended to its history, and the
        entries behind it (the efficiency's ``u_cal``: the history's slope spread and the fit's own)."""
        if self.fit is None:
            return None
        from dyno.analysis.systematic import calibration_rel_u

        entry = self.fit.to_entry("2000-01-01", gear_ratio_brake_per_secondary=self.gear_ratio)
        hist = self.history + [entry]
        return calibration_rel_u(hist, entry), len(hist)

    # --- decision -------------------------------------------------------------------------------
    def accept(self, history_path, *, date: str | None = None, note: str = ""):
        """Append the fit to the history (atomically); only for a fit that passed every check."""
        if not self.acceptable:
            raise CalibrationRejected(self.rejection or f"nothing to accept in phase {self.phase.value}")
        date = date or _dt.datetime.now().replace(microsecond=0).isoformat()
        if not note:
            note = f"dyno calibrate --channel {self.channel}, {len(self.load_steps())} steps"
            if self.repro is not None and self.repro.n > 1:
                note += f", {self.repro.n} repeats, reproducibility {100 * self.repro.rel_sd:.3f} %"
        self.entry = self.fit.to_entry(date, lever_arm_m=self.radius_m,
                                       gear_ratio_brake_per_secondary=self.gear_ratio, note=note)
        append_entry(history_path, self.entry)
        self.phase = Phase.ACCEPTED
        return self.entry

    def reject(self, reason: str = "rejected by the operator") -> None:
        self.rejection = self.rejection or reason
        self.phase = Phase.REJECTED

    def abort(self, cause: str, detail: str) -> None:
        """A fault (or E-stop) ended the calibration: nothing collected so far can be trusted."""
        self.aborted = (cause, detail)
        self.rejection = f"ABORTED ({cause}): {detail}"
        self.phase = Phase.REJECTED
