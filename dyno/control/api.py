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
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from dyno.analysis.stopping import STOP_QUANTILE
from dyno.control.steady import SettleCriteria


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
    # A plan file's identity and its mode's own parameters (dyno.control.planfile): the name it was
    # chosen by, the mode's table (e.g. [speed_hold]) and, for mode "steps", the [[step]] list.
    name: str = ""
    params: dict = field(default_factory=dict, hash=False)
    steps: tuple = ()
    source: str = ""  # the plan file it came from ("" for a plan built in code)
    text: str = field(default="", repr=False, compare=False)  # that file's text (stored as plan.toml)


#: the states in which the brake loads the CVT, and those in which the engine must be running
#: (what the safety monitor expects; a coast-down's deliberate cut aside)
LOADED_STATES = frozenset({State.WARMUP, State.STEP, State.SETTLE, State.MEASURE})
ENGINE_STATES = LOADED_STATES | {State.ARMED}



@dataclass(frozen=True)
class PlanConfig:
    """What a plan may read of the run's configuration (a snapshot; the engine owns the originals).

    ``control``/``inertia``/``rig``: rig.toml's [control], [inertia] and the whole rig description;
    ``input_channel``: the engine-side torque converter (or None); ``tune_path``: the tune a
    characterisation compares with; the ``*_plan``/``speed_hold_gains`` fields: a caller's overrides of a
    mode's own parameters (None: from the plan file).
    """

    limits: object = None
    calibration: object = None
    engine_map: object = None
    control: object = None
    inertia: object = None
    rig: object = None
    input_channel: object = None
    tune_path: object = None
    engagement_plan: object = None
    coast_down_plan: object = None
    speed_hold_plan: object = None
    speed_hold_gains: object = None


@runtime_checkable
class PlanContext(Protocol):
    """All a plan runner may touch (Bluesky's plans-through-a-run-engine): it is handed one and returns.

    The engine (:class:`dyno.control.engine.EngineContext` over the controller) implements it; so does the
    fake rig of the tests (:mod:`dyno.control.fake_rig`).  Every output passes the engine's gate; after a
    safe state the engine has the last word whatever the plan does; tasks a plan needs run under
    :meth:`hold_task` and end with the run; files go through :meth:`write_artifact`.
    """

    plan: TestPlan  #: the frozen plan being run
    config: PlanConfig  #: limits, calibration, engine map, [control], inertias, overrides
    state: State  #: the state table's current state (read-only)
    points: tuple  #: the points recorded so far (read-only)
    throttle_frac: float  #: the throttle as last commanded, 0..1

    def now(self) -> float:
        """Rig seconds: the run's clock (a paced session's scaled clock, else the loop's)."""

    def host_now(self) -> float:
        """Host (loop) seconds: the time base of the log and of the points' windows (their disturbances)."""

    def test_time_s(self) -> float:
        """Rig seconds since GO."""

    async def sleep(self, dt_s: float) -> None:
        """Wait ``dt_s`` rig seconds (the outputs are serviced on the way)."""

    async def checkpoint(self) -> None:
        """Return when the operator has not paused the test."""

    def brake(self, direction: int) -> None:
        """APPLY / RELEASE / STOP the brake actuator, through the engine's gate (APPLY raises after a safe state)."""

    def throttle(self, fraction: float, *, log: bool = True) -> None:
        """The throttle 0 idle .. 1 full, through the gate; remembered for the points."""

    def cut_engine(self) -> None:
        """A deliberate engine cut (coast-down): ignition off, throttle idle, brake released, nothing latched."""

    def rpm(self, channel: int) -> float:
        """The live speed of a Hall channel (``v1.CH_PRIMARY`` / ``v1.CH_SECONDARY``)."""

    def device_now_us(self) -> int:
        """The newest device time seen (µs): the streams' time base."""

    streams: object  #: the acquired streams (edge and ADC windows), read-only

    def phase(self, state: State, reason: str = "") -> None:
        """Enter ``state`` (checked against :data:`TRANSITIONS`; logged; the faces follow)."""

    def log(self, doc_type: str, **fields) -> None:
        """One document of the run's log."""

    async def measure(self, give_up=None, plan: TestPlan | None = None, since_s: float = 0.0) -> tuple:
        """MEASURE a steady window into a point (remeasured if disturbed); ``plan``: the window's own targets;
        ``since_s``: the window began that many seconds ago (the plan saw the rig steady and untouched since).
        Returns (point, host_t0, host_t1)."""

    def record(self, point: dict, host_t0: float, host_t1: float) -> None:
        """Record an accepted point (the faces, the log, the point hooks)."""

    async def warm_up_at_load(self) -> None:
        """The plan's warm-up at load, waited out before the first point."""

    def mark_loaded(self) -> None:
        """The brake has loaded the CVT from now (unless already marked): the warm-up criterion's start."""

    def set_results(self, results: dict, *, hooks: bool = True, log: bool = True) -> None:
        """A characterisation's figures (``hooks``: the simulator adds its truths; ``log``: a document)."""

    def add_truths(self, results: dict) -> None:
        """Let the result hooks (the simulator's truths) annotate ``results`` in place."""

    def tune_control(self, control, identified: dict) -> None:
        """An auto-tune's outcome: the [control] gains for the rest of the run and its record."""

    def hold_task(self, coro, name: str):
        """Run ``coro`` as an engine-owned task (a closed loop beside the plan); cancelled at the end of the run."""

    def fail(self, cause: str, detail: str) -> None:
        """Abort the test: the safe state at once, then the record."""

    def write_artifact(self, name: str, doc: dict) -> None:
        """A JSON file beside the run's log (logged as a warning where it cannot be written)."""


__all__ = ["State", "TRANSITIONS", "TestPlan", "LOADED_STATES", "ENGINE_STATES", "PlanConfig", "PlanContext"]
