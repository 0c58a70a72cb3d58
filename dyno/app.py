"""Composition root: builds a rig (simulated or real), runs a test, writes the run.

The CLI and the UI call these functions; the layers below never import this.
"""

from __future__ import annotations

import asyncio
import datetime as _dt
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from dyno.acquisition.poller import Poller
from dyno.acquisition.reader import make_reader
from dyno.control.controller import SafetyLimits, TestController, TestPlan
from dyno.protocol import v1
from dyno.transports.base import I2CTransport

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_CALIBRATION = REPO_ROOT / "calibration" / "torque_calibration.csv"
DEFAULT_ENGINE_MAP = REPO_ROOT / "calibration" / "engine_maps" / "baja-10hp-representative.csv"


@dataclass
class RunOptions:
    sim: bool = True
    seed: int = 0
    speed: float | None = None  # None: as fast as possible (sim); N: N x real time
    fault_rate: float = 0.0
    faults: object = None  # a dyno.sim.bus.BusFaults, overrides fault_rate
    out_dir: Path | None = None
    protocol: str | None = None
    rig_path: Path | None = None
    calibration_path: Path = DEFAULT_CALIBRATION
    engine_map_path: Path = DEFAULT_ENGINE_MAP
    plan: TestPlan = field(default_factory=TestPlan)
    limits: SafetyLimits | None = None
    clock_offset_us: int = 0
    sim_params: object = None
    auto_go: bool = True
    max_sim_s: float = 3600.0  # a run longer than this is stopped (safety net for sims)
    setup: object = None  # callable(ctx) after assembly, before running (tests inject faults)
    tune_path: Path | None = None  # the CVT tune on the rig (stored with the run); sim: its CVT's tune


def default_run_dir(root: Path = Path("runs")) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    path = root / stamp
    n = 1
    while path.exists():
        n += 1
        path = root / f"{stamp}-{n}"
    return path


def load_inputs(opts: RunOptions):
    """Rig config, calibration entry and engine map; every error names file and field."""
    from dyno.analysis.calibration import latest, load_history
    from dyno.analysis.engine_map import load_engine_map
    from dyno.rigconfig import load_rig

    rig_cfg = load_rig(opts.rig_path)
    calibration = latest(load_history(opts.calibration_path))
    engine_map = load_engine_map(opts.engine_map_path)
    return rig_cfg, calibration, engine_map


def limits_from_config(rig_cfg) -> SafetyLimits:
    lim = rig_cfg.limits
    return SafetyLimits(rotor_temp_max_c=lim.rotor_temp_max_c, overspeed_primary_rpm=lim.overspeed_primary_rpm,
                        overspeed_secondary_rpm=lim.overspeed_secondary_rpm, comms_timeout_s=lim.comms_timeout_s)


@dataclass
class RunContext:
    """What a running test is made of (the UI holds one of these)."""

    poller: Poller
    controller: TestController
    writer: object
    sim: object = None
    thermometer: object = None
    audit: dict = field(default_factory=lambda: {"corrupted_accepted": 0})


def build(opts: RunOptions, now_s) -> RunContext:
    """Assemble poller, controller and run writer for a simulated or real rig."""
    from dyno.runlog.writer import RunWriter

    rig_cfg, calibration, engine_map = load_inputs(opts)
    protocol = opts.protocol or rig_cfg.protocol
    limits = opts.limits or limits_from_config(rig_cfg)
    sim = None
    if opts.sim:
        from dyno.sim.bus import BusFaults
        from dyno.sim.rig import SimRig

        faults = opts.faults or (BusFaults.mixed(opts.fault_rate) if opts.fault_rate else None)
        sim = SimRig(now_s, seed=opts.seed, params=opts.sim_params, protocol=protocol, faults=faults,
                     clock_offset_us=opts.clock_offset_us, full_stroke_s=rig_cfg.actuator.full_stroke_s)
        bus, actuators = sim.bus, sim.actuators
        blocking = False
    else:  # pragma: no cover - needs the rig
        from dyno.hw.outputs import GpioActuators
        from dyno.transports.i2c import open_i2c

        bus = None
        transport = open_i2c(rig_cfg)
        actuators = GpioActuators(rig_cfg)
        blocking = True
    transport = I2CTransport(bus, rig_cfg.i2c.firmware_address) if opts.sim else transport
    reader = make_reader(protocol, transport)
    thermometer = _thermometer(bus if opts.sim else transport.bus, rig_cfg.i2c.thermometer_address)
    poller = Poller(reader, poll_hz=rig_cfg.poll_hz, thermometer=thermometer, blocking_io=blocking)
    out = Path(opts.out_dir) if opts.out_dir else default_run_dir()
    meta = {
        "mode": "sim" if opts.sim else "rig",
        "protocol": protocol,
        "seed": opts.seed if opts.sim else None,
        "fault_rate": opts.fault_rate,
        "rig_config": rig_cfg.path,
        "rig": _asdict(rig_cfg),
        "calibration_source": str(opts.calibration_path),
        "engine_map_source": str(engine_map.source),
        "engine_map_sha256": engine_map.sha256,
        "plan": _asdict(opts.plan),
        "limits": _asdict(limits),
    }
    tune_path = opts.tune_path
    if tune_path is None and sim is not None:
        from dyno.sim.physics import _resolve_map_path  # repo-relative default, as the sim resolves it

        tune_path = getattr(sim.model.params, "cvt_tune_path", None)
        tune_path = _resolve_map_path(tune_path) if tune_path else None
    tune_text = None
    if tune_path is not None:
        import hashlib

        from dyno.tuning.tune import load_tune

        load_tune(tune_path)  # validate: a bad tune is refused before anything is written
        tune_text = Path(tune_path).read_text()
        meta["tune_source"] = str(tune_path)
        meta["tune_sha256"] = hashlib.sha256(tune_text.encode()).hexdigest()
    writer = RunWriter(out, meta, calibration=calibration.to_dict(),
                       engine_map_text=Path(opts.engine_map_path).read_text(), tune_text=tune_text)
    poller.listeners.append(writer.events)
    controller = TestController(poller, actuators, calibration, engine_map, plan=opts.plan, limits=limits,
                                writer=writer, auto_go=opts.auto_go,
                                on_wait_engine=sim.start_engine if sim else None)
    ctx = RunContext(poller, controller, writer, sim, thermometer)
    if sim is not None:
        poller.listeners.append(sim.truth)
        controller.point_hooks.append(sim.truth.point_hook)

        def audit(raw: bytes) -> None:
            if not sim.audit(raw):
                ctx.audit["corrupted_accepted"] += 1

        reader.session.frame_listeners.append(audit)
    return ctx


def _thermometer(bus, address: int):
    """A zero-argument callable returning the rotor temperature in C."""
    try:
        from dyno.hw.thermometer import MLX90614
    except ImportError:  # pragma: no cover - the hw package is part of the install
        return None
    sensor = MLX90614(bus, address)
    return sensor.object_c


def _asdict(obj):
    import dataclasses

    if dataclasses.is_dataclass(obj):
        return {f.name: _asdict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [_asdict(x) for x in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


async def run_test_async(opts: RunOptions) -> dict:
    loop = asyncio.get_running_loop()
    ctx = build(opts, loop.time)
    if opts.setup:
        opts.setup(ctx)
    poll_task = asyncio.create_task(ctx.poller.run())
    status = "fail"
    try:
        try:
            state = await asyncio.wait_for(ctx.controller.run(), opts.max_sim_s if opts.sim else None)
        except TimeoutError:
            ctx.controller.abort("timeout", f"run exceeded {opts.max_sim_s:.0f} s")
            state = ctx.controller.state
        status = "success" if state.value == "done" else "abort"
    finally:
        ctx.poller.stop()
        await asyncio.gather(poll_task, return_exceptions=True)
        ctx.writer.close(status, ctx.controller.reason, link=ctx.poller.link_health(),
                         events_lost=ctx.poller.reader.events_lost)
    return summarize(ctx)


def summarize(ctx: RunContext) -> dict:
    reader = ctx.poller.reader
    st = reader.stats
    frames = {"read": st.read, "accepted": st.accepted, "rejected": dict(sorted(st.rejected.items())),
              "rejected_total": sum(st.rejected.values()),
              "transport_errors": dict(sorted(st.transport_errors.items())),
              "device_resets": st.device_resets, "resyncs": st.resyncs}
    out = {"run_dir": str(ctx.writer.run_dir), "state": ctx.controller.state.value,
           "reason": ctx.controller.reason, "points": [public_point(p) for p in ctx.controller.points],
           "frames": frames, "events_lost": reader.events_lost, "aborts": ctx.controller.aborts}
    if ctx.sim is not None:
        frames["corrupted_accepted"] = ctx.audit["corrupted_accepted"]
        out["faults_injected"] = dict(ctx.sim.bus.injected)
        out["sim_time_s"] = ctx.sim.model.t_s
    return out


POINT_KEYS = ("index", "rpm_primary", "rpm_secondary", "ratio", "torque_secondary_nm", "power_out_w", "power_in_w",
              "efficiency", "efficiency_sem", "rpm_primary_std", "rpm_secondary_std", "torque_secondary_std_nm",
              "n_primary_edges", "n_secondary_edges", "n_adc", "duration_s", "settled_by", "valid",
              "efficiency_true", "rpm_primary_true", "rpm_secondary_true", "torque_secondary_true_nm", "faults")


def public_point(p: dict) -> dict:
    out = {}
    for k in POINT_KEYS:
        if k in p:
            v = p[k]
            out[k] = None if isinstance(v, float) and math.isnan(v) else v
    return out


def run_test(opts: RunOptions) -> dict:
    from dyno.clock import run

    if opts.sim:
        return run(run_test_async(opts), virtual=True, speed=opts.speed)
    return run(run_test_async(opts), virtual=False)  # pragma: no cover - needs the rig
