"""Fault drills on the simulated rig: cause recorded, safe state reached, true latency, nothing lost.

Each drill runs the real composition root (``dyno run --sim`` in-process, signal
handlers included) with a shortened plan.  Latencies are in true (simulated) time
from the physical onset recorded by the drill (or, for over-temperature and
over-speed, the moment the simulated truth crossed the limit).
"""

import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.cli.run_cmd import exit_code
from dyno.control.safety import SafetyLimits
from dyno.session.drills import parse_drill
from dyno.errors import ConfigError
from dyno.runlog.replay import replay
from dyno.runlog.reader import load_run

from .conftest import IDEAL, QUICK_PLAN, STARTUP_HOLD_S, rig_without_run_enable

REPO = Path(__file__).resolve().parents[2]

# drill -> (onset s after the start-up hold, accepted causes, bound on the true latency in s)
_RISKY = {
    "hall-dead:primary": (32.0, {"sensor_fault"}, 0.5),
    "hall-dead:secondary": (32.0, {"sensor_fault", "stall"}, 0.5),
    "hall-dead:both": (32.0, {"sensor_fault", "stall"}, 0.5),
    "thermometer-stuck": (32.0, {"sensor_fault", "over_temperature"}, 5.0),
    "thermometer-lost": (32.0, {"thermometer_lost", "over_temperature"}, 5.0),
    "adc-error": (32.0, {"sensor_fault"}, 0.1),
    "adc-stuck": (32.0, {"sensor_fault"}, 2.0),
    "bus-lost": (32.0, {"comms_lost"}, 0.25 + 0.1),
    "overspeed": (4.0, {"overspeed"}, 0.1),
    "loop-stall:800": (32.0, {"watchdog"}, 0.5 + 0.1),
    "controller-crash": (32.0, {"error"}, 0.1),
    "disk-full": (32.0, {"disk_full"}, 0.1),
}
RISKY = {name: (round(STARTUP_HOLD_S + t, 3), causes, bound) for name, (t, causes, bound) in _RISKY.items()}


def _run(tmp_path, drills, *, seed=3, limits=None, name="run", mock_pins=False, rig_path=None):
    captured = {}

    def setup(ctx):
        captured["ctx"] = ctx

    r = run_test(RunSpec(sim=True, seed=seed, out_dir=tmp_path / name, plan=QUICK_PLAN, limits=limits, sim_params=IDEAL,
                            drills=[parse_drill(d) for d in drills], handle_signals=True, setup=setup,
                            mock_pins=mock_pins, rig_path=rig_path))
    return r, captured["ctx"]


def _assert_kept_and_replays(r):
    """Every point accepted before the fault is on disk and replays to the same numbers."""
    run = load_run(r["run_dir"])
    on_disk = run.points
    assert len(on_disk) == len(r["points"])
    rep = replay(r["run_dir"])["points"]
    for live, again in zip(r["points"], rep):
        assert again["efficiency"] == pytest.approx(live["efficiency"], rel=1e-12, abs=1e-12)


def _assert_points_honest(r):
    """Each point within its own uncertainty of the simulated truth (4 sigma, + 0.2 pp for bias)."""
    for p in r["points"]:
        assert abs(p["efficiency"] - p["efficiency_true"]) <= 4 * p["efficiency_sem"] + 0.002, p


def _assert_safe(r, ctx):
    assert r["rig_safe"] is True
    assert r["outputs"]["throttle"] == "idle" and r["outputs"]["engine_kill"] == "killed"
    assert r["outputs"]["brake_actuator"] in ("releasing", "stopped")
    m = ctx.sim.model
    assert m.throttle_frac == 0.0 and not m.engine_enabled and m.actuator_dir <= 0
    # the release stroke completed after the abort: the brake is off
    assert m.actuator_mm == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("drill", sorted(RISKY))
def test_drill_aborts_safe_within_bound(tmp_path, drill):
    t, causes, bound = RISKY[drill]
    r, ctx = _run(tmp_path, [f"{drill}@{t}"])
    assert r["state"] == "aborted", r["reason"]
    a = r["aborts"][0]
    assert a["cause"] in causes, a
    assert a["drill"].startswith(drill)
    assert 0.0 <= a["latency_s"] <= bound, a
    assert a["detection_s"] <= a["latency_s"] + 1e-9
    assert exit_code(r) == 3
    _assert_safe(r, ctx)
    if drill != "overspeed":  # (over-speed is drilled in the warm-up, before any point)
        assert len(r["points"]) >= 2, "the drill should hit a run that already has points"
    _assert_kept_and_replays(r)
    logged = load_run(r["run_dir"]).docs("abort")
    if drill != "disk-full":  # a full disk takes the abort record with it; the JSON carries it
        assert logged and logged[0]["cause"] == a["cause"]


MOCK_PIN_DRILLS = ["bus-lost", "overspeed", "adc-error", "loop-stall:800", "controller-crash", "hall-dead:primary"]


@pytest.mark.parametrize("drill", MOCK_PIN_DRILLS)
def test_drill_through_the_real_rig_output_code(tmp_path, drill):
    """--mock-pins: GpioActuators on gpiozero's MockFactory drive the physics; same bounds, pins safe."""
    from dyno.hw.outputs import GpioActuators
    from dyno.hw.testing import assert_direction_never_switched_with_enable_on

    t, causes, bound = RISKY[drill]
    r, ctx = _run(tmp_path, [f"{drill}@{t}"], mock_pins=True)
    act = ctx.controller.act
    assert isinstance(act, GpioActuators)
    assert r["state"] == "aborted" and exit_code(r) == 3
    a = r["aborts"][0]
    assert a["cause"] in causes and 0.0 <= a["latency_s"] <= bound, a
    # outputs read back from the pins: throttle idle, ignition killed, actuator off after its release
    assert r["rig_safe"] is True and r["outputs"]["brake_actuator"] == "stopped", r["outputs"]
    assert r["outputs"]["throttle"] == "idle" and r["outputs"]["engine_kill"] == "killed"
    m = ctx.sim.model
    assert m.throttle_frac == 0.0 and not m.engine_enabled and m.actuator_mm == pytest.approx(0.0, abs=1e-9)
    factory = act._enable.pin_factory
    assert_direction_never_switched_with_enable_on(factory.log, ctx.rig_cfg)
    _assert_kept_and_replays(r)


def test_overtemp_latency_from_the_true_crossing(tmp_path):
    """Rotor heating at 20 C/s: safe within 0.3 s of the true crossing (or before it); overshoot stated."""
    r, ctx = _run(tmp_path, ["overtemp@20"], limits=SafetyLimits(rotor_temp_max_c=120.0))
    a = r["aborts"][0]
    assert a["cause"] == "over_temperature"
    truth_cross = ctx.sim.truth.crossing_s("rotor_c", 120.0, 20.0)
    assert a["latency_s"] is not None and a["latency_s"] <= 0.3, a
    if truth_cross is None:  # compensation for the sensor lag safed it before the limit: negative latency
        assert a["latency_s"] < 0.0 and a["onset_basis"] == "extrapolated", a
        assert r["drills"][0]["hazard_arose"] is False and "below" in r["drills"][0]["hazard_note"]
    else:
        assert a["onset_s"] == pytest.approx(truth_cross) and r["drills"][0]["hazard_arose"] is True
    assert a["overshoot_c"] <= 20.0 * 0.3
    _assert_safe(r, ctx)


def test_frozen_thermometer_cannot_hide_overheating(tmp_path):
    """The issue's case: the thermometer freezes near a 90 C limit; the rotor never gets 10 C over it."""
    r, ctx = _run(tmp_path, ["thermometer-stuck@52"], limits=SafetyLimits(rotor_temp_max_c=90.0))
    a = r["aborts"][0]
    assert r["state"] == "aborted" and a["cause"] in ("sensor_fault", "over_temperature")
    assert a["latency_s"] <= 5.0
    assert ctx.sim.truth.max_after("rotor_c", 52.0) <= 90.0 + 10.0


def test_lost_thermometer_guarded_by_the_thermal_estimate(tmp_path):
    r, ctx = _run(tmp_path, ["thermometer-lost@58"], limits=SafetyLimits(rotor_temp_max_c=90.0))
    assert r["state"] == "aborted" and r["aborts"][0]["cause"] in ("thermometer_lost", "over_temperature")
    assert ctx.sim.truth.max_after("rotor_c", 58.0) <= 90.0 + 10.0


def test_device_reset_cuts_the_engine_through_the_run_enable(tmp_path):
    """Issue 37: the Nano's run-enable is in the kill chain; a reset drops it (pins high-Z, pull-down), so the
    engine stops by wiring and the host aborts naming the reset; nothing recorded is lost."""
    t = _mid_window_s(tmp_path)
    r, ctx = _run(tmp_path, [f"device-reset@{t}"], name="wired")
    assert r["state"] == "aborted" and exit_code(r) == 3
    a = r["aborts"][0]
    assert a["cause"] == "nano_reset" and "watchdog" in a["detail"], a
    cut = ctx.sim.model.engine_cut(t - 1e-6)
    assert cut is not None and cut[1] == "nano" and cut[0] - t <= 0.01  # the physics: the chain opened at the reset
    assert r["outputs"]["engine_cut_by"] == "nano" and r["rig_safe"]
    assert r["supervisor"]["drops"][0]["cause"] == "reset (watchdog)"
    _assert_kept_and_replays(r)


def test_device_reset_is_survived_and_its_window_discarded(tmp_path):
    """Without the run-enable in the kill chain (supervisor_timeout_s = 0) the link rides through resets."""
    t = _mid_window_s(tmp_path)
    r, ctx = _run(tmp_path, ["device-reset@0.1", f"device-reset@{t}"], rig_path=rig_without_run_enable(tmp_path))
    assert r["state"] == "done", r["reason"]
    assert any("reset" in d["reason"] for d in r["discarded"])
    assert r["frames"]["device_resets"] >= 2
    assert r["frames"]["corrupted_accepted"] == 0
    assert len(r["points"]) >= 8
    _assert_points_honest(r)
    _assert_kept_and_replays(r)


def _mid_window_s(tmp_path, k=3):
    """The middle of point k's measurement window in a drill-free run (runs are deterministic)."""
    clean, _ = _run(tmp_path, [], name="clean")
    p = clean["points"][k]
    return round(0.5 * (p["host_t_start_s"] + p["host_t_end_s"]), 2)


def test_short_loop_stall_is_survived_and_counted(tmp_path):
    """200 ms: within the loop's liveness limit (the Nano's 0.2 s + the I/O thread's 0.05 s tolerance, less two
    poll periods: docs/safety.md), so nothing is cut."""
    t = _mid_window_s(tmp_path)
    r, ctx = _run(tmp_path, [f"loop-stall:200@{t}"])
    assert r["state"] == "done", r["reason"]
    # the poller's I/O path reads on while the loop is held (the rig's I/O thread; the simulated one polls from
    # a background ticker): the Nano's heartbeat (0.2 s) is served, its ring never overflows
    assert r["events_lost"] == 0 and r["supervisor"]["drops"] == []
    assert ctx.sim.model.engine_cut() is None or ctx.sim.model.engine_cut()[1] == "pi"  # (the end of the test)
    assert r["discarded"], "the point whose window spans the stall must be discarded"
    assert any("late" in d["reason"] or "no poll" in d["reason"] for d in r["discarded"]), r["discarded"]
    assert not ctx.watchdog.tripped
    _assert_points_honest(r)


def test_a_loop_stall_past_the_liveness_limit_cuts_the_engine(tmp_path):
    """300 ms > the liveness limit (issue 49): the I/O thread's stand-in polls on only while the loop's stamp is
    fresh, so the Nano's heartbeat stops and its run-enable opens the kill chain while the loop is still stalled;
    the host latches when it resumes."""
    t = _mid_window_s(tmp_path)
    r, ctx = _run(tmp_path, [f"loop-stall:300@{t}"])
    rec = next(d for d in r["drills"] if d["name"] == "loop-stall")
    assert r["state"] == "aborted" and exit_code(r) == 3 and rec["hazard_arose"]
    t_cut, by = ctx.sim.model.engine_cut(rec["onset_s"])
    assert by == "nano" and t_cut < rec["onset_s"] + 0.3  # (the physics: cut during the stall)
    assert r["supervisor"]["drops"][0]["cause"] == "heartbeat"
    assert r["aborts"][0]["cause"] in ("nano_heartbeat", "watchdog") and r["rig_safe"]
    assert not ctx.watchdog.tripped  # (0.3 s < its 0.5 s: the Nano alone cut)
    _assert_kept_and_replays(r)


def test_dead_sensors_never_end_done(tmp_path):
    """The issue's cases: both Halls dead, ADC error on every conversion -> aborted, never "done"."""
    r, _ = _run(tmp_path, ["hall-dead:both@0"], name="halls")
    assert r["state"] == "aborted" and exit_code(r) == 3
    # the engine cannot be seen to start: the ignition is not left enabled for long
    assert r["aborts"][0]["cause"] in ("stall", "sensor_fault") and r["aborts"][0]["trigger_s"] <= STARTUP_HOLD_S + 61
    r, _ = _run(tmp_path, ["adc-error@0"], name="adc")
    assert r["state"] == "aborted" and r["aborts"][0]["cause"] == "sensor_fault"


@pytest.mark.parametrize("text", ["nope@1", "hall-dead@1", "hall-dead:left@1", "overtemp:3@1", "overtemp",
                                  "loop-stall:-5@1", "loop-stall:x@1", "overtemp@inf", "overtemp@-1"])
def test_bad_drill_is_refused(text):
    with pytest.raises(ConfigError, match="--drill"):
        parse_drill(text)


def _dyno(*args, **kw):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "dyno", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO, env=env, timeout=600, **kw)


@pytest.mark.parametrize("sig", ["sigint", "sigterm", "sighup"])
def test_signal_drill_as_a_real_process(tmp_path, sig):
    """The process signals itself mid-test: safe state, abort + stop record, JSON printed, exit 128+N.

    At 60 s from the first frame: mid-test, points done by then (the torque zero read at rest before GO
    takes 4 s; the default plan's points take ~5-6 s each and its last ends ~120 s after the first frame)."""
    out = tmp_path / "run"
    p = _dyno("run", "--sim", "--headless", "--json", "--out", out, "--drill", f"{sig}@60")
    signum = int(getattr(signal, sig.upper()))
    assert p.returncode == 128 + signum, p.stderr
    assert "Traceback" not in p.stderr
    r = json.loads(p.stdout)
    assert r["state"] == "aborted" and r["aborts"][0]["cause"] == "signal"
    assert r["rig_safe"] is True and r["aborts"][0]["latency_s"] <= 0.1
    run = load_run(out)
    assert run.docs("abort")[0]["cause"] == "signal"
    assert run.stop["exit_status"] == "abort"
    assert len(run.points) == len(r["points"]) >= 2


def test_external_sigterm_leaves_an_abort_record(tmp_path):
    """A signal from outside (systemd stop, terminal closed) at a random moment: same ending."""
    out = tmp_path / "run"
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.Popen([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--json", "--speed", "20",
                             "--out", str(out)], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    deadline = 120
    import time

    t0 = time.monotonic()
    while not (out / "documents.jsonl").exists() or b'"point"' not in (out / "documents.jsonl").read_bytes():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < deadline
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "Traceback" not in stderr
    r = json.loads(stdout)
    assert r["state"] == "aborted" and r["rig_safe"]
    assert load_run(out).stop["exit_status"] == "abort"


def test_disk_full_drill_as_a_real_process(tmp_path):
    out = tmp_path / "run"
    p = _dyno("run", "--sim", "--headless", "--json", "--out", out, "--drill", "disk-full@60")  # (mid-test: see above)
    assert p.returncode == 3
    assert "Traceback" not in p.stderr
    err_lines = [ln for ln in p.stderr.splitlines() if ln.strip() and not ln.startswith("dyno run: rig file ")]
    assert len(err_lines) == 1 and "No space left" in err_lines[0] and str(out) in err_lines[0]
    r = json.loads(p.stdout)
    assert r["aborts"][0]["cause"] == "disk_full" and r["rig_safe"]
    rep = replay(out)  # what is on disk stays readable
    assert len(rep["points"]) == len(r["points"]) >= 2
    assert not any(isinstance(v, float) and math.isnan(v) for v in r.values())


def test_mock_pins_drill_as_a_real_process(tmp_path):
    """`dyno run --sim --mock-pins --drill ...` as a user types it: the real-rig output code ends safe."""
    r = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--json", "--mock-pins",
                        "--drill", "bus-lost@30", "--out", str(tmp_path / "run")], capture_output=True, text=True,
                       timeout=300, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert r.returncode == 3, r.stderr
    out = json.loads(r.stdout)
    a = out["aborts"][0]
    assert a["cause"] == "comms_lost" and a["latency_s"] <= 0.35
    assert out["rig_safe"] is True and out["outputs"]["brake_actuator"] == "stopped"
    # the physics' own position beside the driver's 0-1 estimate (GpioActuators has no position sensor)
    o = out["outputs"]
    assert o["brake_position_mm"] <= 1.0 and o["pads_off_rotor"] is True  # inside the 1.0 mm free travel
    assert o["brake_estimate"] == 0.0 and o["driver_released"] is True
    assert o["driver_release_basis"] == "end_of_travel"  # the shipped rig declares the end switch
    assert 0.0 <= o["release_s"] <= o["release_bound_s"]


def test_doctor_toggle_on_the_sim_as_a_real_process(tmp_path):
    """`dyno doctor --sim --toggle`: the outputs through HardwareRig (watchdog running), report OK."""
    r = subprocess.run([sys.executable, "-m", "dyno", "doctor", "--sim", "--toggle"], capture_output=True,
                       text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(REPO)}, cwd=tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "watchdog running" in r.stdout and "brake step" in r.stdout and "rig OK" in r.stdout
