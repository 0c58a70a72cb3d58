"""Composition root: builds a rig (simulated or real), runs a test, writes the run.

The CLI and the UI call these functions; the layers below never import this.
"""

from __future__ import annotations

import asyncio
import datetime as _dt
import math
from dataclasses import dataclass, field
from pathlib import Path

from dyno.acquisition.poller import Poller
from dyno.session.after import close_run, end_test
from dyno.acquisition.reader import make_reader
from dyno.session.ambient import ambient_sensor, run_ambient, sim_bme280_address
from dyno.session.signals import RunSignals
from dyno.session.next_run import abort_on_write_error
from dyno.session.safety import kick_on_polls, make_watchdog, uncuttable_warning, watchdog_beat
from dyno.session.running import RunningTest
from dyno.session.shift_prediction import shift_prediction_for
from dyno.session import input_channel as app_input  # rig.toml [input_torque]: the engine-side channel (issue 27)
from dyno.control import registry  # the plan modes' runners, handed to the controller (_build)
from dyno.control.safety import SafetyLimits
from dyno.control.controller import TestController
from dyno.control.api import TestPlan
from dyno.transports.base import I2CTransport
from dyno.resources import DEFAULT_ENGINE_MAP
from dyno.rig.locate import find_rig
from dyno.session.calibration_files import calibration_in_force



@dataclass(frozen=True)
class RunSpec:
    """What a run is to be: built by the CLI, the UI session or a test, read once by :func:`build`.

    Frozen: a change is a new spec (``dataclasses.replace``); nothing is added to a run after it is built.
    """

    sim: bool = True
    seed: int = 0
    speed: float | None = None  # None: as fast as possible (sim); N: N x real time
    fault_rate: float = 0.0
    faults: object = None  # a dyno.sim.bus.BusFaults, overrides fault_rate
    out_dir: Path | None = None
    protocol: str | None = None
    rig_path: Path | None = None
    calibration_path: Path = field(default_factory=calibration_in_force)  # the state directory's, else shipped
    engine_map_path: Path = DEFAULT_ENGINE_MAP
    plan: TestPlan = field(default_factory=TestPlan)  # (the CLI's default is the speed-hold plan file)
    limits: SafetyLimits | None = None
    clock_offset_us: int = 0
    sim_params: object = None
    auto_go: bool = True
    max_sim_s: float = 3600.0  # a run longer than this is stopped (safety net for sims)
    setup: object = None  # callable(ctx) after assembly, before running (tests inject faults)
    # real rig only: injectable parts (tests run the real-rig path on MockFactory and a simulated bus)
    pin_factory: object = None
    rig_bus: object = None
    serial_port: object = None
    tune_path: Path | None = None  # the CVT tune on the rig (stored with the run); sim: its CVT's tune
    drills: list = field(default_factory=list)  # dyno.session.drills.Drill, armed from the first frame (sim only)
    handle_signals: bool = False  # SIGINT/SIGTERM/SIGHUP -> safe state + abort record (the CLI sets it)
    finish_release: bool = True  # after the test, service the outputs until the brake release stroke ends
    mock_pins: bool = False  # sim: drive the physics through the real-rig output code (dyno.hw.mockpins)
    firmware_elf: Path | None = None  # sim: the Nano's real ELF in simavr between the physics and the host
    ambient: object = None  # dyno.analysis.air.Ambient given on the command line (--ambient), else rig.toml/sensor
    # the live session's scaled clock (dyno.session.pacing.ScaledClock: simulated time on a real-time loop); None: the
    # simulated rig's time is the loop's (a virtual loop), or the real rig
    clock: object = None
    on_belt_table_build: object = None  # callable(tune name): the simulated CVT solves its table (a minute)
    runners: dict = field(default_factory=dict)  # this run's own plan modes beside the shipped ones (tests, benches)
    listeners: tuple = ()  # the face's controller listeners, callables(controller): given to its constructor


def default_run_dir(root: Path | None = None) -> Path:
    """A new run directory ``<root>/<timestamp>[-N]``, created here: claimed atomically (``mkdir`` fails on
    a name another process took in the meantime, and the next suffix is tried), so runs started together
    never pick the same one."""
    if root is None:
        from dyno.runlog.files import runs_root

        root = runs_root()  # $DYNO_RUNS_DIR, else $DYNO_STATE_DIR/runs
    root.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    for n in range(1, 100_000):
        path = root / (stamp if n == 1 else f"{stamp}-{n}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        return path
    raise FileExistsError(root / stamp)


def load_inputs(opts: RunSpec):
    """Rig config, calibration entry and engine map; every error names file and field."""
    from dyno.analysis.calibration_history import latest, load_history
    from dyno.analysis.engine_map import load_engine_map
    from dyno.rig.config import load_rig
    from dyno.rig.locate import find_rig, require_own_rig

    found = find_rig(opts.rig_path)
    if not opts.sim:
        require_own_rig(found)  # the shipped rig file's pins are never guessed onto hardware
    rig_cfg = load_rig(found.path)
    from dyno.transports.budget import check_budget

    rig_cfg = check_budget(rig_cfg)  # a poll rate the link cannot carry: derated (said), or refused naming poll_hz
    calibration = latest(load_history(opts.calibration_path))
    engine_map = load_engine_map(opts.engine_map_path)
    return rig_cfg, calibration, engine_map


def systematic_terms(opts: RunSpec, rig_cfg, calibration, engine_map=None) -> dict:
    """The systematic terms every point states beside its CI (dyno.analysis.systematic; meta.json keeps them),
    with what each assumes (``u95_terms``, dyno.analysis.u95_terms): the map's term is the map file's stated
    uncertainty, else rig.toml's ``engine_map_rel``."""
    from dyno.analysis import u95_terms
    from dyno.analysis.calibration_history import load_history
    from dyno.analysis.systematic import calibration_rel_u

    history = load_history(opts.calibration_path)
    cal = calibration_rel_u(history, calibration)
    emap, basis = u95_terms.map_basis(engine_map, rig_cfg.uncertainty.engine_map_rel)
    measured = u95_terms.map_measured(engine_map)
    terms = u95_terms.base_terms(cal, len(history), emap, basis, measured)
    wear = {} if measured else {"engine_wear_max_frac": u95_terms.ENGINE_WEAR_MAX_FRAC}  # (one-sided: systematic)
    if wear:
        terms.append(u95_terms.engine_wear_term(wear["engine_wear_max_frac"]))
    return {"torque_calibration_rel": cal, "engine_map_rel": emap, "calibration_entries": len(history),
            **wear, "u95_terms": terms}


def limits_from_config(rig_cfg) -> SafetyLimits:
    lim = rig_cfg.limits
    return SafetyLimits(rotor_temp_max_c=lim.rotor_temp_max_c, overspeed_primary_rpm=lim.overspeed_primary_rpm,
                        overspeed_secondary_rpm=lim.overspeed_secondary_rpm, comms_timeout_s=lim.comms_timeout_s,
                        check_period_s=SafetyLimits.check_period_s)


@dataclass
class RunContext:
    """What a running test is made of (the UI holds one of these)."""

    poller: Poller
    controller: TestController
    writer: object
    sim: object = None
    thermometer: object = None
    audit: dict = field(default_factory=lambda: {"corrupted_accepted": 0})
    watchdog: object = None
    drills: object = None  # dyno.session.drills.DrillRunner
    rig_cfg: object = None
    signal_received: int | None = None
    hw: object = None  # dyno.hw.rig.HardwareRig on the real rig (closed by close_rig)
    # host (loop) time -> simulated time; None: the same clock (a virtual loop). The UI paces the physics
    # on a scaled clock, so its drill latencies convert the controller's trigger times with this.
    host_to_sim: object = None
    ambient: dict = field(default_factory=dict)  # the run's air (meta.json "ambient"; "end": the reading after)
    ambient_sensor: object = None  # the BME280 driver when the rig has one
    twin: object = None  # dyno.hw.mockpins.SimPinFactory: the wiring twin under --mock-pins
    estop: object = None  # dyno.hw.estop.EstopInput where rig.toml declares pins.estop_input (rig or twin)
    pi_outputs: bool = False  # the outputs are the Pi's own code (the rig, or the twin): the rig's signal path
    estop_hooked: bool = False  # the E-stop input records its stops through this context (start_watchdog)
    link_meter: object = None  # dyno.transports.budget.LinkMeter: the firmware link's time on the wire
    u95_terms: list | None = None  # what each term of efficiency_u95 assumes (dyno.analysis.u95_terms)


def open_rig(rig_cfg, *, pin_factory=None, bus=None, serial_port=None):
    """The real rig's parts, assembled in one place (:class:`dyno.hw.rig.HardwareRig`).

    Entering claims the pins in the safe state, opens the firmware link that
    ``rig.toml`` names (I2C with the Nano's RESET line, or USB serial) and the
    thermometer, and builds the watchdog.  Signals are the entry point's job
    (each installs handlers that leave an abort record); ``close_rig`` finishes
    the release stroke and releases everything.
    """
    from dyno.hw.rig import HardwareRig

    hw = HardwareRig(rig_cfg, pin_factory=pin_factory, bus=bus, serial_port=serial_port, install_signals=False)
    return hw.__enter__()


def close_rig(ctx) -> None:
    sim = getattr(ctx, "sim", None)
    if sim is not None:
        sim.close()  # (--firmware-elf: the simavr harness ends with the run)
    hw = getattr(ctx, "hw", None)
    if hw is not None:
        hw.__exit__(None, None, None)
    if getattr(ctx, "twin", None) is not None:  # --mock-pins: the run is recorded; release the mock pins
        from dyno.session.safety import close_twin

        close_twin(ctx)


def build(opts: RunSpec, now_s) -> RunContext:
    """Assemble poller, controller and run writer for a simulated or real rig.

    The one composition root: ``dyno run``, ``dyno ui`` (through the live session) and
    the safety they get (monitor, watchdog, drills, signal handlers) all come from here.
    """
    rig_cfg, calibration, engine_map = load_inputs(opts)
    uncertainty = systematic_terms(opts, rig_cfg, calibration, engine_map)
    from dyno.session.drills_wiring import check_wiring_drill

    if opts.drills and not opts.sim:
        from dyno.errors import ConfigError

        raise ConfigError("command line", "--drill", "drills run on the simulated rig only (--sim)")
    for d in opts.drills:  # before anything is built or written: a drill this rig cannot have is bad input
        check_wiring_drill(d, rig_cfg, opts.sim and opts.mock_pins)
    hw = None
    if not opts.sim:
        hw = open_rig(rig_cfg, pin_factory=opts.pin_factory, bus=opts.rig_bus, serial_port=opts.serial_port)
    try:
        return _build(opts, now_s, rig_cfg, calibration, engine_map, uncertainty, hw)
    except BaseException:
        if hw is not None:  # the pins were claimed: leave them safe and released
            hw.__exit__(None, None, None)
        raise


def _supervisor_command(protocol: str, limits, rig_cfg) -> bytes | None:
    """SET_SUPERVISOR with the run's over-speed limits and the rig file's heartbeat timeout (v2; 0: not armed)."""
    from dyno.protocol import v2

    timeout_s = rig_cfg.limits.supervisor_timeout_s
    if protocol != "v2" or timeout_s <= 0:
        return None
    return v2.supervisor_command(limits.overspeed_primary_rpm, limits.overspeed_secondary_rpm, timeout_s)


def _build(opts: RunSpec, now_s, rig_cfg, calibration, engine_map, uncertainty: dict, hw) -> RunContext:
    from dyno.runlog.writer import RunWriter

    protocol = opts.protocol or rig_cfg.protocol
    limits = opts.limits or limits_from_config(rig_cfg)
    sim = twin = estop = None
    clock = opts.clock if opts.sim else None  # the live session's scaled clock (None: the loop's time is the sim's)
    speed = clock.speed if clock is not None else 1.0
    plan = opts.plan  # in rig seconds, never rewritten: a paced controller times it on the scaled clock
    if opts.sim:
        from dyno.sim.bus import BusFaults
        from dyno.sim.elf_firmware import elf_spec as _elf_spec
        from dyno.sim.rig import SimRig

        if clock is not None:
            now_s = clock.now
        faults = opts.faults or (BusFaults.mixed(opts.fault_rate) if opts.fault_rate else None)
        sim = SimRig(now_s, seed=opts.seed, params=app_input.sim_params_for(opts.sim_params, rig_cfg),
                     protocol=protocol, faults=faults,
                     clock_offset_us=opts.clock_offset_us, full_stroke_s=rig_cfg.actuator.full_stroke_s,
                     run_enable_wired=rig_cfg.limits.supervisor_timeout_s > 0,  # D7 in the kill chain
                     brake_hold_relay=rig_cfg.actuator.brake_hold_relay, pace=speed,  # K3: as rig.toml declares it
                     bme280_address=sim_bme280_address(rig_cfg),  # (the air sensor too)
                     firmware_elf=_elf_spec(opts.firmware_elf, rig_cfg, protocol))  # (None: the Python emulation)
        bus, actuators = sim.bus, sim.actuators
        sim.model.engine_enabled = False  # the Pi's outputs from power-up: the engine killed (the chain open)
        if opts.mock_pins:  # the Pi's own output code and E-stop input over a twin of the wiring
            from dyno.session.safety import twin_outputs

            actuators, twin, estop = twin_outputs(rig_cfg, sim, now_s, opts.seed)
        elif clock is not None:  # the controller ticks with the loop's time; the stroke is timed in the sim's
            from dyno.session.pacing import SimTimeActuators

            actuators = SimTimeActuators(sim.actuators, clock.now)
        blocking = False
    else:
        actuators, estop = hw.actuators, hw.estop
        blocking = opts.rig_bus is None  # real buses block: transfers run in a thread
    map_source = engine_map.source
    input_channel = app_input.load_input_channel(rig_cfg)  # rig.toml [input_torque], or None
    ambient_dev = ambient_sensor(rig_cfg, sim=sim, hw=hw)
    ambient = run_ambient(rig_cfg, opts.ambient, ambient_dev)  # (a declared sensor that fails: ConfigError)
    if ambient.corrected:  # the engine makes the day's power, not the standard day's (SAE J1349)
        engine_map = engine_map.at_ambient(ambient.temp_c, ambient.dry_pressure_kpa)
    site_m = rig_cfg.ambient.altitude_m  # the interval's asymmetric terms (dyno.analysis.systematic.interval_basis)
    uncertainty.update(air_rel=ambient.air_rel_u(site_m), air_day=None if ambient.corrected else {"altitude_m": site_m},
                       driveline_loss_max_frac=rig_cfg.driveline.loss_max_frac,
                       driveline_drag_max_nm=rig_cfg.driveline.drag_max_nm)
    app_input.state_terms(uncertainty, ambient, input_channel)  # what each u95 term assumes
    link_meter = None
    if opts.sim:  # each transaction charged its wire time at the rig file's clock (dyno.transports.budget)
        from dyno.transports.budget import LinkMeter, MeteredBus

        link_meter = LinkMeter(now_s)
        firmware_bus = MeteredBus(bus, link_meter, rig_cfg)
        transport = I2CTransport(firmware_bus, rig_cfg.i2c.firmware_address)
        # the thermometer shares the firmware's bus on an I2C rig (on a serial rig it has its own)
        thermometer = _thermometer(firmware_bus if rig_cfg.transport == "i2c" else bus,
                                   rig_cfg.i2c.thermometer_address)
    else:  # I2C with the Nano's RESET line wired in, or USB serial: each transfer timed as it happens
        from dyno.transports.budget import metered_rig_link

        transport, thermometer, link_meter = metered_rig_link(hw, rig_cfg)
    reader = make_reader(protocol, transport, supervisor_command=_supervisor_command(protocol, limits, rig_cfg),
                         want_input=input_channel is not None)  # (asked for at every boot: docs/protocol.md)
    # paced: each real-time poll spans `speed` x more rig time, so it may drain that many more frames
    poller = Poller(reader, poll_hz=rig_cfg.poll_hz, thermometer=thermometer, blocking_io=blocking,
                    max_burst=max(8, math.ceil(8 * speed)))
    meta = {
        "mode": "sim" if opts.sim else "rig",
        "protocol": protocol,
        "seed": opts.seed if opts.sim else None,
        "fault_rate": opts.fault_rate,
        "rig_config": rig_cfg.path,
        "rig_file": find_rig(opts.rig_path).to_dict(),  # which file and how it was found (dyno.rig.locate)
        "rig": _asdict(rig_cfg),
        "calibration_source": str(opts.calibration_path),
        "engine_map_source": str(map_source),
        "engine_map_sha256": engine_map.sha256,
        "plan": plan_meta(plan),
        "uncertainty": uncertainty,
        "ambient": ambient.to_dict(),  # the one place the air is read from (library, report, replay)
        "limits": _asdict(limits),
        **app_input.input_meta(input_channel),
    }
    tune_path = opts.tune_path
    if tune_path is None and sim is not None:
        from dyno.sim.rig_params import resolve_map_path  # repo-relative default, as the sim resolves it

        tune_path = getattr(sim.model.params, "cvt_tune_path", None)
        tune_path = resolve_map_path(tune_path) if tune_path else None
    tune_text = tune = None
    if tune_path is not None:
        import hashlib

        from dyno.tuning.tune import load_tune

        tune = load_tune(tune_path)  # validate: a bad tune is refused before anything is written
        tune_text = Path(tune_path).read_text()
        meta["tune_source"] = str(tune_path)
        meta["tune_sha256"] = hashlib.sha256(tune_text.encode()).hexdigest()
    plan_text = opts.plan.text or None
    if plan_text:
        import hashlib

        meta["plan_source"] = opts.plan.source
        meta["plan_text_sha256"] = hashlib.sha256(plan_text.encode()).hexdigest()
    out = Path(opts.out_dir) if opts.out_dir else default_run_dir()  # (last: a bad input leaves no directory)
    # Every callback is given to its part's constructor.  Those that act on the controller (the log's write error,
    # the watchdog's beat, the points' terms) are made before it and reach it when called (it exists by then).
    controller = None
    writer = RunWriter(out, meta, calibration=calibration.to_dict(),
                       engine_map_text=Path(opts.engine_map_path).read_text(), tune_text=tune_text,
                       plan_text=plan_text,  # (a re-arm's next run: the same error callback, dyno.session.next_run)
                       on_error=abort_on_write_error(lambda: controller, out))
    poller.listeners.append(writer.events)
    watchdog = make_watchdog(actuators, hw, estop, rig_cfg.actuator.watchdog_s, now_s)
    controller = TestController(poller, actuators, calibration, engine_map, plan=plan, limits=limits,
                                writer=writer, auto_go=opts.auto_go,
                                on_wait_engine=sim.start_engine if sim else None,
                                runner_for=_runner_for(opts.runners), from_idle=registry.FROM_IDLE,  # (the plan modes)
                                rig=rig_cfg, control=rig_cfg.control, inertia=rig_cfg.inertia,  # [control], [inertia]
                                tune_path=tune_path,  # (stored with the run; the faces' overlay)
                                shift_prediction=shift_prediction_for(tune, engine_map),  # the characterisations'
                                input_channel=input_channel,  # the live screen's T_in; tared at the first point
                                clock=clock,  # rig time for the plan (None: the loop's; safety stays on the loop)
                                point_hooks=_point_hooks(uncertainty, input_channel, poller, sim, lambda: ctx.controller),
                                result_hooks=_result_hooks(sim),
                                heartbeat_hooks=(watchdog_beat(watchdog, lambda: controller,
                                                               rig_cfg.actuator.watchdog_s),),
                                # the kill-path probe found no way to stop the engine: said at once; the face's own
                                listeners=(uncuttable_warning(), *opts.listeners))
    kick_on_polls(poller, watchdog)
    drills = None
    if opts.drills:  # armed when the test starts (dyno.session.running.RunningTest.start), from the first frame
        from dyno.session.drills import DrillRunner

        drills = DrillRunner(opts.drills, asyncio.get_running_loop(), sim_now=clock.now if clock is not None else None,
                             speed=clock.speed if clock is not None else 1.0)
    if sim is not None:
        poller.listeners.append(sim.truth)
    ctx = RunContext(poller, controller, writer, sim, thermometer, rig_cfg=rig_cfg, hw=hw,
                     ambient=ambient.to_dict(), ambient_sensor=ambient_dev, link_meter=link_meter,
                     twin=twin, estop=estop, watchdog=watchdog, drills=drills,
                     pi_outputs=hw is not None or twin is not None,  # the outputs are the Pi's code (signal path)
                     host_to_sim=clock.host_to_sim if clock is not None else None,  # drills' true-time latencies
                     u95_terms=uncertainty.get("u95_terms"))  # what each term assumes (dyno.session.summary)
    if sim is not None:
        def audit(raw: bytes) -> None:
            if not sim.audit(raw):
                ctx.audit["corrupted_accepted"] += 1

        reader.session.frame_listeners.append(audit)
    return ctx


def _result_hooks(sim) -> tuple:
    """The simulated rig's truths added to a characterisation's figures."""
    if sim is None:
        return ()
    from dyno.sim.driven import results_truth_hook

    return (results_truth_hook(sim.model),)


def _point_hooks(unc: dict, input_channel, poller, sim, controller_of) -> list:
    """What every point gets beside its reduction, in order: the systematic terms, the input channel's figure
    (after the map's terms: it stays beside), the simulated rig's truth.  ``controller_of``: the run's
    controller now (a re-arm's next one takes the hooks over: its own tare, its own log)."""
    hooks = []
    if unc:
        from dyno.analysis.systematic import calibration_rel_for, interval_basis, point_systematic

        hooks.append(lambda point, t0, t1: point.update(point_systematic(
            point, calibration_rel_for(unc["torque_calibration_rel"], point, controller_of().tare),
            unc["engine_map_rel"], unc["air_rel"], **interval_basis(unc, point))))
    if input_channel is not None:
        hooks.append(app_input.InputPointHook(controller_of, input_channel, poller.streams, unc or {}))
    if sim is not None:
        hooks.append(sim.truth.point_hook)
    return hooks


def _runner_for(extra: dict):
    """The plan modes' runners: the shipped table (dyno.control.registry), with the spec's own modes."""
    if not extra:
        return registry.runner_for
    return lambda mode: extra[mode] if mode in extra else registry.runner_for(mode)


def _thermometer(bus, address: int):
    """A zero-argument callable returning the rotor temperature in C."""
    try:
        from dyno.hw.thermometer import MLX90614
    except ImportError:  # pragma: no cover - the hw package is part of the install
        return None
    sensor = MLX90614(bus, address)
    return sensor.object_c


def plan_meta(plan) -> dict:
    """The plan as meta.json keeps it (its file's text is stored beside, as plan.toml)."""
    d = _asdict(plan)
    d.pop("text", None)
    return d


def _asdict(obj):
    import dataclasses

    if dataclasses.is_dataclass(obj):
        return {f.name: _asdict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [_asdict(x) for x in obj]
    if isinstance(obj, dict):
        return {k: _asdict(v) for k, v in obj.items()}
    if isinstance(obj, Path):
        return str(obj)
    return obj


async def run_test_async(opts: RunSpec) -> dict:
    loop = asyncio.get_running_loop()
    # The handlers go in before the run directory is made: a signal while the rig is built waits for it,
    # then ends the run like one that came a moment later (not a directory holding a `start` alone).
    signals = RunSignals(loop).install() if opts.handle_signals else None
    try:
        ctx = build(opts, loop.time)
    except BaseException:
        if signals is not None:
            signals.restore()
        raise
    if opts.setup:
        opts.setup(ctx)
    run = RunningTest(ctx, loop)
    run.start(signals=signals)
    status = "fail"
    try:
        state = await run.run_controller(opts.max_sim_s if opts.sim else None)
        status = "success" if state.value == "done" else "abort"
        await end_test(ctx, finish_release=opts.finish_release)  # (the UI's session ends its tests through it too)
    finally:
        await run.stop()
        if signals is not None:
            signals.restore()
        try:
            result = close_run(ctx, status)  # the air after the run, the summary, the safety document, the log closed
        finally:
            close_rig(ctx)
    return result


def run_test(opts: RunSpec) -> dict:
    from dyno.clock import run
    from dyno.session.heap import return_free_heap

    try:
        if opts.sim:
            from dyno.sim.belt_table import announcing_builds

            with announcing_builds(opts.on_belt_table_build):  # (a table solved for this run is said so)
                return run(run_test_async(opts), virtual=True, speed=opts.speed)
        return run(run_test_async(opts), virtual=False)  # pragma: no cover - needs the rig
    finally:  # a process that runs test after test must not keep each run's freed pages (dyno.session.heap)
        return_free_heap()
