"""The meeting point of the test engine and the plans: the state table and the plan's data.

:class:`~dyno.control.controller.TestController` (the engine: state machine, safety, the outputs'
gate) and the plan runners (:mod:`dyno.control.plans` and the modules it names) both depend on
this module, never on each other: a runner gets the controller as an argument and drives it
through its methods, using :class:`State` and :class:`TestPlan` from here.  So the dependency runs
one way (engine -> api <- plans) and nothing here imports the engine or a plan module; it is a
leaf (only :mod:`dyno.control.steady` and :mod:`dyno.analysis`).  ``dyno.control.controller``
re-exports all three names.

::

    IDLE -> WAIT_ENGINE -> ARMED --GO--> WARMUP -> STEP -> SETTLE -> MEASURE -+-> STEP ...
                                                                              +-> DONE
    any state --(E-stop, over-temperature, lost link, over-speed, error)--> ABORTED
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from dyno.analysis.stopping import STOP_QUANTILE
from dyno.control.hold_law import HoldGains
from dyno.control.steady import SettleCriteria

if TYPE_CHECKING:  # (types only: the engine's collaborators, not imported at run time)
    from dyno.analysis.calibration_history import CalibrationEntry
    from dyno.analysis.engine_map import EngineMap
    from dyno.control.readings import Readings
    from dyno.control.safety import SafetyLimits
    from dyno.rig.config import ControlConfig
    from dyno.rig.inertia import InertiaConfig


class State(enum.Enum):
    IDLE = "idle"
    WAIT_ENGINE = "wait_engine"
    ARMED = "armed"
    WARMUP = "warmup"
    STEP = "step"
    SETTLE = "settle"
    MEASURE = "measure"
    DONE = "done"
    ABORTED = "aborted"


TRANSITIONS: dict[State, set[State]] = {
    State.IDLE: {State.WAIT_ENGINE},
    State.WAIT_ENGINE: {State.ARMED},
    State.ARMED: {State.WARMUP},
    State.WARMUP: {State.STEP},
    State.STEP: {State.SETTLE, State.STEP, State.DONE},  # (speed hold: next setpoint, or none left)
    State.SETTLE: {State.MEASURE, State.DONE, State.STEP},  # (speed hold: a setpoint it cannot hold)
    State.MEASURE: {State.STEP, State.DONE, State.MEASURE},
    State.DONE: set(),
    State.ABORTED: set(),
}
for _s in State:
    if _s not in (State.DONE, State.ABORTED):
        TRANSITIONS[_s].add(State.ABORTED)


@dataclass(frozen=True)
class TestPlan:
    __test__ = False  # a plan, not a pytest class (tests import it by name)
    engine_running_rpm: float = 1300.0  # primary above this = engine started
    engine_detect_s: float = 0.5
    # Ignition enabled and no primary rpm for this long: the engine was not started, or its
    # Hall sensor is dead (an engine running unseen would be blind to over-speed): abort.
    engine_start_timeout_s: float = 60.0
    warmup_s: float = 3.0  # full throttle, no brake: let it stabilise
    # Warm-up criterion: no point is measured before the brake has loaded the CVT this long (belt and
    # clutch warm-up; the rig has no belt-temperature channel, only the rotor's). Recorded with the run.
    warmup_at_load_s: float = 0.0
    step_s: float = 0.25  # brake actuator on-time per step (adapted, see below)
    step_min_s: float = 0.08
    step_max_s: float = 1.0
    target_points: int = 20  # adapt the step so the run gives about this many points
    measure_s: float = 3.0  # the thesis's 3 s average (the minimum)
    target_efficiency_sem: float = 0.0012  # extend the average until the standard error is this small ...
    target_efficiency_ci95: float | None = None  # ... or, if set, until the 95 % half-width is this small ...
    max_measure_s: float = 24.0  # ... or this long (rotor heat limits how long a point can last)
    measure_check_s: float = 1.0  # the stopping rule looks this often (its bound covers frequent looks)
    stop_quantile: float = STOP_QUANTILE  # the targets are met by the error's upper bound at this level
    min_point_torque_nm: float = 4.0  # below this the brake has not really loaded the CVT: no point
    settle_mode: str = "detect"  # "detect" (from the data) or "fixed" (thesis: 4 s)
    mode: str = "step"  # "step" (the thesis's open-loop steps) or a runner in dyno.control.registry.RUNNERS
    settle: SettleCriteria = field(default_factory=SettleCriteria)
    min_secondary_rpm: float = 1500.0  # stop when the secondary falls below this
    max_points: int = 60
    expected_secondary_span_rpm: float = 4500.0  # light load to min, for the step adaptation
    # A plan file's identity and its mode's own parameters (dyno.control.planfile): the name it was chosen
    # by, and the mode's table (e.g. [speed_hold], or the [[step]] list) as the mode's dataclass
    # (dyno.control.registry.PARAMS).
    name: str = ""
    params: Any = field(default=None, hash=False)  # the mode's typed parameters (None: the mode's defaults)
    source: str = ""  # the plan file it came from ("" for a plan built in code)
    text: str = field(default="", repr=False, compare=False)  # that file's text (stored as plan.toml)


#: the states in which the brake loads the CVT, and those in which the engine must be running
#: (what the safety monitor expects; a coast-down's deliberate cut aside)
LOADED_STATES = frozenset({State.WARMUP, State.STEP, State.SETTLE, State.MEASURE})
ENGINE_STATES = LOADED_STATES | {State.ARMED}



@runtime_checkable
class ShiftPrediction(Protocol):
    """What the tune under test predicts of its shift (the characterisation compares with it).  The root
    builds it from the tune and the engine map (:mod:`dyno.session.shift_prediction`); a plan reads no file."""

    tune_name: str
    ratio_low_stop: float
    ratio_high_stop: float

    def engagement_rpm(self) -> float:
        """The engine speed at which the clutch engages."""

    def shift_out_rpm_full_load(self) -> float:
        """The engine speed at which the ratio leaves its low stop at full load."""

    def shift_out_at_load_rpm(self, torque_secondary_nm: float) -> float:
        """The shift-out speed at a (light) measured secondary load."""


@dataclass(frozen=True)
class PlanConfig:
    """What a plan may read of the run's configuration (a snapshot; the engine owns the originals).

    ``limits``: the safety limits (the plan keeps clear of them; the engine enforces them);
    ``calibration``: the gauge's, tared at GO; ``engine_map``: the map at the day (None: no map);
    ``control``: rig.toml's [control] (the holds' gains); ``inertia``: rig.toml's [inertia];
    ``shift_prediction``: the tune's predicted shift (None: no tune or no map).
    """

    limits: SafetyLimits
    calibration: CalibrationEntry | None
    engine_map: EngineMap | None
    control: ControlConfig | None
    inertia: InertiaConfig
    shift_prediction: ShiftPrediction | None = None


@dataclass(frozen=True)
class Hold:
    """A closed-loop hold of ``variable`` at ``setpoint`` by the brake (``ctx.hold``; build one with
    :func:`SpeedHold`, :func:`EngineHold` or :func:`TorqueHold`).

    ``setpoint``: rpm for "secondary" and "engine", N·m for "torque".  Reached: within ``tolerance_rel``
    of it for ``in_band_s`` and, where ``settle_rate_rel_per_s`` > 0, the secondary's rate over two
    adjacent ``settle_rate_window_s`` means below that; not reached by ``max_approach_s``: the result
    says so.  ``load_raises``: more brake raises the speed (the engine while the CVT back-shifts; the
    torque always).
    ``gains``: the law's (None: the rig's [control] for the variable).  ``rate_per_s`` > 0: the setpoint
    moves from the one held now towards ``setpoint`` at this rate (a ramp).  ``wait`` False: return at
    once (the hold goes on).
    """

    variable: str
    setpoint: float
    tolerance_rel: float = 0.0075
    in_band_s: float = 0.8
    max_approach_s: float = 8.0
    settle_rate_rel_per_s: float = 0.0
    settle_rate_window_s: float = 0.3
    load_raises: bool = False
    gains: HoldGains | None = None
    rate_per_s: float = 0.0
    wait: bool = True

    @property
    def unit(self) -> str:
        return "N·m" if self.variable == "torque" else "rpm"


def SpeedHold(rpm: float, **kw) -> Hold:  # noqa: N802  (a request's constructor, named as the request)
    """Hold the secondary at ``rpm``."""
    return Hold("secondary", rpm, **kw)


def EngineHold(rpm: float, **kw) -> Hold:  # noqa: N802
    """Hold the engine (primary) at ``rpm``."""
    return Hold("engine", rpm, **kw)


def TorqueHold(nm: float, **kw) -> Hold:  # noqa: N802
    """Hold the secondary torque at ``nm`` (a wider default band: the firing ripple)."""
    kw.setdefault("tolerance_rel", 0.03)
    return Hold("torque", nm, **kw)


@dataclass(frozen=True)
class HoldResult:
    """How a hold went: ``reached`` (module :class:`Hold`), the variable's last ``value`` (its unit), the
    rig seconds it took (``settle_s``) and since the brake last moved (``quiet_s``)."""

    reached: bool
    value: float
    settle_s: float
    quiet_s: float


@runtime_checkable
class PlanContext(Protocol):
    """All a plan runner may touch (Bluesky's plans-through-a-run-engine): it is handed one and returns.

    The engine (:class:`dyno.control.engine.EngineContext` over the controller) implements it.  Every
    output passes the engine's gate; after a safe state the engine has the last word whatever the plan
    does.  A plan starts no task: a closed loop is a :meth:`hold`, which the engine runs and ends.
    docs/architecture.md says why each member is here.
    """

    plan: TestPlan  #: the frozen plan being run
    config: PlanConfig  #: limits, calibration, engine map, [control], [inertia], the tune's prediction
    state: State  #: the state table's current state (read-only)
    read: Readings  #: the rig's speeds, torque and raw windows (dyno.control.readings)

    def now(self) -> float:
        """Rig seconds: the run's clock (a paced session's scaled clock, else the loop's)."""

    async def sleep(self, dt_s: float) -> None:
        """Wait ``dt_s`` rig seconds (the outputs are serviced on the way)."""

    async def checkpoint(self) -> None:
        """Return when the operator has not paused the test."""

    def brake(self, direction: int) -> None:
        """APPLY / RELEASE / STOP the brake actuator, through the engine's gate; ends a hold under way."""

    def throttle(self, fraction: float, *, log: bool = True) -> None:
        """The throttle 0 idle .. 1 full, through the gate; remembered for the points."""

    def cut_engine(self) -> None:
        """A deliberate engine cut (coast-down): ignition off, throttle idle, brake released, nothing latched."""

    async def hold(self, request: Hold) -> HoldResult:
        """Hold a variable by the brake (:class:`Hold`); the hold goes on after it returns, until the next
        request, a brake command, or the end of the run.  A measurement freezes it for its window."""

    async def bounded(self, step: Coroutine, limit: Callable[[], str | None]) -> str | None:
        """Run ``step`` (a coroutine of the plan's) while the engine asks ``limit`` every 50 ms; when it
        gives a reason, the step is cancelled and the reason returned (None: the step ended by itself)."""

    def phase(self, state: State, reason: str = "") -> None:
        """Enter ``state`` (checked against :data:`TRANSITIONS`; logged; the faces follow)."""

    def log(self, doc_type: str, **fields) -> None:
        """One document of the run's log."""

    async def measure(self, give_up: Callable[[], bool] | None = None, plan: TestPlan | None = None,
                      since_s: float = 0.0, fixed_s: float | None = None) -> tuple[dict, float, float]:
        """MEASURE a steady window into a point (remeasured if disturbed), a hold frozen meanwhile;
        ``plan``: the window's own targets; ``since_s``: the window began that many seconds ago (the plan
        saw the rig steady and untouched since); ``fixed_s``: a window of that length, no stopping rule,
        the hold not frozen (a ramp).  Returns (point, host_t0, host_t1)."""

    def record(self, point: dict, host_t0: float, host_t1: float) -> None:
        """Record an accepted point (the faces, the log, the point hooks)."""

    async def loaded(self, *, wait_warm_up: bool = False) -> None:
        """The brake loads the CVT from now (unless already marked): the warm-up at load's clock starts;
        ``wait_warm_up``: also wait out the plan's warm-up at load (a measurement does so by itself)."""

    def set_results(self, results: dict, *, truths: bool = True, log: bool = True) -> None:
        """A characterisation's figures, with ``test_time_s`` (``truths``: the simulator adds its own;
        ``log``: a ``characterisation`` document).  Called again, the figures replace the last."""

    def fail(self, cause: str, detail: str) -> None:
        """Abort the test: the safe state at once, then the record."""

    def write_artifact(self, name: str, doc: dict) -> None:
        """A JSON file beside the run's log (logged as a warning where it cannot be written)."""


__all__ = ["State", "TRANSITIONS", "TestPlan", "LOADED_STATES", "ENGINE_STATES", "PlanConfig", "PlanContext",
           "Hold", "HoldResult", "SpeedHold", "EngineHold", "TorqueHold", "ShiftPrediction"]
