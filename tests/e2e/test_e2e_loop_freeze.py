"""Drill ``loop-freeze`` (issue 49): only the control loop stops; its I/O thread and the watchdog thread run on.

Must-shows: the engine is cut by the Nano or the Pi's watchdog (``outputs.engine_cut_by``), the drill's
``latency_s`` (freeze -> the kill chain opening, as the physics sees it) is within the heartbeat timeout +
0.1 s, the pads come off the rotor through K3, the host latches when it resumes and the run directory replays;
through the real-rig output code (``--mock-pins``, the loop frozen inside one of the driver's commands, holding
its lock) the watchdog thread's kill relay opens while the loop is still frozen.
"""

import pytest

from dyno.cli.run_cmd import exit_code
from dyno.errors import ConfigError
from dyno.runlog.reader import load_run
from dyno.runlog.replay import replay
from dyno.session.drills import parse_drill
from dyno.session.root import RunSpec, run_test

from .conftest import bench_safe_state_module, QUICK_PLAN, drill_as_the_user_runs_it

TIMEOUT_S = 0.2  # hardware/rig.toml [limits] supervisor_timeout_s
WATCHDOG_S = 0.5  # hardware/rig.toml [actuator] watchdog_s


def _run(tmp_path, drills, *, mock_pins=False, name="run"):
    held = {}
    r = run_test(RunSpec(sim=True, seed=3, out_dir=tmp_path / name, plan=QUICK_PLAN,
                            drills=[parse_drill(d) for d in drills], setup=lambda ctx: held.update(ctx=ctx),
                            mock_pins=mock_pins))
    return r, held["ctx"]


def _assert_cut_while_frozen(r, ctx):
    assert r["state"] == "aborted" and exit_code(r) == 3
    rec = next(d for d in r["drills"] if d["name"] == "loop-freeze")
    assert rec["freeze_s"] == 3.0 and rec["hazard_arose"]
    # the I/O thread's stand-in ran all through the freeze: it polled while the loop's stamp was fresh, then
    # looked every period and held the heartbeat (3 s at 150 Hz: ~450 looks)
    assert 1 <= rec["io_polls_during_freeze"] <= 20 and rec["io_ticks_held"] > 300, rec
    model = ctx.sim.model
    t_cut, by = model.engine_cut(rec["onset_s"])  # the physics: the kill chain opened, by whom
    assert by in ("nano", "pi") and rec["engine_cut_by"] == by and r["outputs"]["engine_cut_by"] == by
    assert 0.0 < t_cut - rec["onset_s"] <= TIMEOUT_S + 0.1
    assert rec["latency_s"] == pytest.approx(t_cut - rec["onset_s"]) and rec["latency_within_bound"]
    assert t_cut < rec["resumed_s"]  # while the loop was still frozen
    # K3 released the brake by wiring while the loop was frozen
    assert rec["k3_fitted"] and rec["pads_off_within_bound"] and rec["pads_off_at_s"] < rec["resumed_s"], rec
    # the host latched when it resumed (the Nano's drop and the watchdog's trip are both on record)
    assert r["aborts"][0]["cause"] in ("nano_heartbeat", "watchdog")
    assert r["aborts"][0]["safe_commanded_s"] >= rec["onset_s"]
    assert r["supervisor"]["drops"][0]["cause"] == "heartbeat"
    assert ctx.controller.act.latched and r["outputs"]["pads_off_rotor"] and r["rig_safe"]
    # the watchdog thread (0.5 s) cut too, while the loop was frozen
    assert ctx.watchdog.tripped
    assert rec["pi_kill_at_s"] is not None and rec["pi_kill_at_s"] - rec["onset_s"] <= WATCHDOG_S + 0.1, rec
    run = load_run(r["run_dir"])
    assert len(run.docs("point")) == len(r["points"])
    assert replay(r["run_dir"])["points"] is not None
    return rec


def test_loop_freeze_the_nano_cuts_while_the_io_thread_runs(tmp_path):
    r, ctx = _run(tmp_path, ["loop-freeze@loaded+2"])
    rec = _assert_cut_while_frozen(r, ctx)
    assert rec["engine_cut_by"] == "nano" and not rec["inside_driver_call"]


def test_loop_freeze_inside_a_driver_call_the_watchdog_cuts_without_its_lock(tmp_path):
    """--mock-pins: the loop freezes inside a GpioActuators command, holding its lock; the watchdog thread's
    kill relay opens while it is held (the driver's own safe state waits for the lock)."""
    r, ctx = _run(tmp_path, ["loop-freeze@loaded+2"], mock_pins=True)
    rec = _assert_cut_while_frozen(r, ctx)
    assert rec["inside_driver_call"]
    assert r["outputs"]["driver_agrees"], r["outputs"].get("driver_disagreement")


def test_without_the_lock_free_cut_the_watchdog_waits_for_the_frozen_command(tmp_path, monkeypatch):
    """The contrast that shows the lock matters: without ``cut_engine_now`` the watchdog's safe state is deferred
    until the frozen command returns (its kill relay is not written during the freeze)."""
    from dyno.hw.outputs import GpioActuators

    monkeypatch.delattr(GpioActuators, "cut_engine_now")
    r, ctx = _run(tmp_path, ["loop-freeze@loaded+2"], mock_pins=True)
    rec = next(d for d in r["drills"] if d["name"] == "loop-freeze")
    assert ctx.watchdog.tripped and rec["pi_kill_at_s"] is None
    assert rec["engine_cut_by"] == "nano"  # (the Nano still cut: two independent paths)


def test_a_short_loop_freeze_cuts_nothing(tmp_path):
    """0.1 s: within the liveness limit; the run goes on, no drop, the record says the hazard did not arise."""
    r, ctx = _run(tmp_path, ["loop-freeze:0.1@loaded+2"])
    rec = next(d for d in r["drills"] if d["name"] == "loop-freeze")
    assert r["state"] == "done" and not rec["hazard_arose"] and "heartbeat" in rec["hazard_note"]
    assert r["supervisor"]["drops"] == [] and not ctx.watchdog.tripped


def test_loop_freeze_argument_is_checked():
    assert parse_drill("loop-freeze@loaded+1").arg is None
    assert parse_drill("loop-freeze:1.5@2").arg == "1.5"
    for bad in ("loop-freeze:0@1", "loop-freeze:x@1", "loop-freeze:700@1"):
        with pytest.raises(ConfigError, match="loop-freeze"):
            parse_drill(bad)


def test_loop_freeze_as_the_user_runs_it(tmp_path):
    """The command itself: exit 3, the JSON's verdict, ``dyno replay`` of the run directory exits 0."""
    r = drill_as_the_user_runs_it(tmp_path / "cli", "--mock-pins", "--drill", "loop-freeze@loaded+2")
    rec = next(d for d in r["drills"] if d["name"] == "loop-freeze")
    assert r["outputs"]["engine_cut_by"] in ("nano", "pi") and rec["latency_s"] <= TIMEOUT_S + 0.1


@pytest.mark.parametrize("mode", ["sim", "mock"])
def test_loop_freeze_in_the_plans_by_drills_matrix(tmp_path, mode):
    """bench/bench_safe_state.py's matrix row for every shipped plan, the loop frozen 2 s after the pads first bite:
    physically safe, rig_safe agrees with the physics, release and latency within their bounds (its judge)."""
    bench = bench_safe_state_module()
    assert bench.DRILLS["loop-freeze"] == pytest.approx(TIMEOUT_S + 0.1)
    fired = 0
    for plan in bench.PLANS:
        row = bench.run_one(plan, "loop-freeze@loaded+2", mode, str(tmp_path / f"{plan}-{mode}"))
        assert bench.judge(row) == [], (plan, row)
        if row["fired"] and row["hazard_arose"]:
            fired += 1
            assert row["state"] == "aborted" and row["exit"] == 3 and row["latency_s"] <= TIMEOUT_S + 0.1, row
    assert fired >= len(bench.PLANS) - 1  # (coast-down never loads the brake: its drill never fires)
