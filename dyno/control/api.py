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

__all__ = ["State", "TRANSITIONS", "TestPlan", "LOADED_STATES", "ENGINE_STATES"]
