"""The kill chain proven before each run (issue 49 item 6): at idle, after ARMED and the tare, the Pi's kill relay
and then the Nano's run-enable are each opened 100 ms, and the engine's speed must dip on the Hall edges.

Judged on the simulated world: the kill chain's own record (``model.ignition_log``: who opened it, when), the
true engine speed in each probe's window (``sim.truth``), whether the engine still fires at the end
(``model.magneto_fires``) and the brake actuator's true travel (never past the free travel: no load).
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.cli.run_cmd import exit_code
from dyno.control import kill_probe
from dyno.session.drills import parse_drill
from dyno.session.root import RunSpec, run_test
from dyno.session.safety import KILL_LEAD_WARNING

from .conftest import bench_safe_state_module, QUICK_PLAN, drill_as_the_user_runs_it

REPO = Path(__file__).resolve().parents[2]


def _run(tmp_path, drills=(), *, mock_pins=False, name="run"):
    held = {}
    r = run_test(RunSpec(sim=True, seed=3, out_dir=tmp_path / name, plan=QUICK_PLAN,
                            drills=[parse_drill(d) for d in drills], setup=lambda ctx: held.update(ctx=ctx),
                            mock_pins=mock_pins))
    return r, held["ctx"]


def _openings(model, t0, t1):
    """(t, by) of every opening of the kill chain in [t0, t1] (sim time), from the physics' record, once the chain
    first closed (before that it is open from the start: the start-up release holds the ignition off)."""
    t0 = max(t0, model.ignition_enabled_at_s or 0.0)
    return [(t, by) for t, on, by in model.ignition_log if not on and t0 < t <= t1]


def _never_loaded(ctx) -> bool:
    m = ctx.sim.model
    return max(ctx.sim.truth.act) <= m.brake.a0_mm and m.pads_off


@pytest.mark.parametrize("mock_pins", [False, True])
def test_a_sound_chain_is_proven_and_the_test_runs_on(tmp_path, mock_pins):
    """Both paths cut the engine (the physics: the chain opened by the Pi, then by the Nano, each ~100 ms; the
    true speed fell) and the host saw each dip on its Hall edges; the engine re-fired and the test ran to its
    points.  ``--mock-pins``: the Pi's own output code (GpioActuators on the wiring twin) opens the relay."""
    r, ctx = _run(tmp_path, mock_pins=mock_pins)
    kp = r["kill_probe"]
    assert kp["ok"] is True and [p["path"] for p in kp["paths"]] == ["pi_relay", "nano_run_enable"]
    m = ctx.sim.model
    go_host_s = ctx.controller.go_s
    opened = _openings(m, 0.0, go_host_s)
    assert [by for _, by in opened] == ["pi", "nano"], opened
    log = m.ignition_log
    for t_open, _ in opened:  # each opening closed again after ~100 ms (the chain's own record)
        t_close = next(t for t, on, _ in log if on and t > t_open)
        assert t_close - t_open == pytest.approx(kill_probe.CUT_S, abs=0.01)
    for p in kp["paths"]:
        assert p["cut"] is True and p["dip_rpm"] >= p["needed_rpm"] >= kill_probe.DIP_MIN_RPM, p
        assert p["recovered_s"] is not None  # the engine re-fired and came back to its idle
    from dyno.session.drills_kill import probe_true_dips

    true_dips = probe_true_dips(ctx)
    for p in kp["paths"]:  # the host's dip is the engine's: within the two-revolution averaging of the truth's fall
        assert true_dips[p["path"]] >= kill_probe.DIP_MIN_RPM
        assert p["dip_rpm"] <= true_dips[p["path"]] + 5.0, (p, true_dips)
    # the probe is rig time before GO, a small share of the run: the two cuts, their observation and recovery
    assert kp["probe_s"] < 4 * (kill_probe.CUT_S + kill_probe.OBSERVE_S) + 2 * kill_probe.RECOVER_MAX_S
    assert r["state"] == "done" and exit_code(r) == 0 and r["points"]
    assert r["rig_safe"] and not m.magneto_fires
    assert r["outputs"]["safe_commanded_s"] > go_host_s  # the run's safe state is its end, not a probe's cut


def _assert_ended_before_any_load(r, ctx, path):
    assert r["state"] == "aborted" and exit_code(r) == 3 and not r["points"]
    (a,) = [a for a in r["aborts"] if a["cause"] == "kill_path_failed"]
    assert a["path"] == path and a["state"] == "armed", a
    assert ctx.controller.go_s is None  # never reached GO
    assert _never_loaded(ctx)  # the brake never applied: the true actuator never left its free travel
    rec = r["drills"][0]
    assert rec["hazard_arose"] and rec["path"] == path
    return rec["probe_true_dips_rpm"]


def test_kill_relay_welded_ends_the_test_at_the_pi_relay(tmp_path):
    r, ctx = _run(tmp_path, ["kill-relay-welded@0"])
    dips = _assert_ended_before_any_load(r, ctx, "pi_relay")
    m = ctx.sim.model
    # the physics: the Pi's probe never opened the chain (the engine's true speed did not fall), the Nano's did
    assert not [by for _, by in _openings(m, 0.0, 1e9) if by == "pi"]
    assert abs(dips["pi_relay"]) < kill_probe.DIP_MIN_RPM / 2 and dips["nano_run_enable"] >= kill_probe.DIP_MIN_RPM
    # the host cut the engine through the path left (the Nano's run-enable, latched): it really stopped firing
    assert m.engine_cut() and r["outputs"]["engine_cut_by"] == "nano" and not m.magneto_fires
    assert r["rig_safe"] and r["supervisor"]["run_enable"] is False


def test_run_enable_shorted_ends_the_test_at_the_nano_run_enable(tmp_path):
    r, ctx = _run(tmp_path, ["run-enable-shorted@0"])
    dips = _assert_ended_before_any_load(r, ctx, "nano_run_enable")
    m = ctx.sim.model
    assert abs(dips["nano_run_enable"]) < kill_probe.DIP_MIN_RPM / 2 and dips["pi_relay"] >= kill_probe.DIP_MIN_RPM
    # the device did drop D7 for the pulse (its truth), but the shorted driver kept the chain closed
    assert any(cause == "pulse" for _, on, cause in ctx.sim.firmware.run_enable_log if not on)
    assert not [by for _, by in _openings(m, 0.0, 1e9) if by == "nano"]
    assert r["outputs"]["engine_cut_by"] == "pi" and not m.magneto_fires and r["rig_safe"]


def test_kill_lead_open_nothing_cuts_and_the_run_says_so(tmp_path):
    r, ctx = _run(tmp_path, ["kill-lead-open@0"])
    dips = _assert_ended_before_any_load(r, ctx, "kill_lead")
    m = ctx.sim.model
    # the chain did open for both probes (and for the safe state), yet the engine never stopped firing
    assert [by for _, by in _openings(m, 0.0, 1e9)][:2] == ["pi", "nano"]
    assert all(abs(d) < kill_probe.DIP_MIN_RPM / 2 for d in dips.values()), dips
    assert m.magneto_fires and m.engine_running and ctx.sim.truth.rp[-1] > 1000.0
    assert r["rig_safe"] is False and "cannot be cut" in r["rig_unsafe_because"]
    assert "own switch or fuel" in r["aborts"][0]["detail"]


def test_kill_lead_open_as_the_user_runs_it(tmp_path):
    """``dyno run --sim --drill kill-lead-open@0``: exit 3, the cause and path in the JSON, and the operator told
    on stderr to stop the engine at its own switch or fuel (the table on screen: the ABORT line)."""
    r = drill_as_the_user_runs_it(tmp_path / "json", "--drill", "kill-lead-open@0")
    assert r["aborts"][0]["cause"] == "kill_path_failed" and r["aborts"][0]["path"] == "kill_lead"
    assert r["rig_safe"] is False and not r["points"]
    p = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--out", str(tmp_path / "screen"),
                        "--drill", "kill-lead-open@0"], capture_output=True, text=True, timeout=600,
                       env={**os.environ, "PYTHONPATH": str(REPO)})
    assert p.returncode == 3, p.stderr[-2000:]
    assert KILL_LEAD_WARNING in p.stderr
    assert "ABORT: kill_path_failed" in p.stdout and "own switch or fuel" in p.stdout and "rig safe: NO" in p.stdout


@pytest.mark.parametrize("drill", ["kill-relay-welded", "run-enable-shorted", "kill-lead-open"])
def test_kill_drills_through_the_pis_own_output_code(tmp_path, drill):
    """``--mock-pins``: the relay path is opened by GpioActuators through the wiring twin; the same verdicts."""
    from dyno.session.drills_kill import KILL_DRILL_PATH

    r, ctx = _run(tmp_path, [f"{drill}@0"], mock_pins=True)
    _assert_ended_before_any_load(r, ctx, KILL_DRILL_PATH[drill])
    assert r["rig_safe"] is (drill != "kill-lead-open")


def test_kill_drills_in_the_plans_by_drills_matrix(tmp_path):
    """bench/bench_safe_state.py's rows for the kill-chain drills: every shipped plan ends at the probe, before
    its first load, with that cause and path (its judge), whatever the plan would have done after GO."""
    bench = bench_safe_state_module()
    cases = [c for c in bench.matrix(bench_args(bench)) if c[1].partition("@")[0] in bench.KILL]
    assert {c[0] for c in cases} == set(bench.PLANS) and {c[1] for c in cases} == {f"{d}@0" for d in bench.KILL}
    for i, (plan, drill, mode) in enumerate(cases):
        if (i % len(bench.KILL)) != bench.PLANS.index(plan) % len(bench.KILL):
            continue  # one drill per plan here (each plan meets a different one; the bench runs them all)
        row = bench.run_one(plan, drill, mode, str(tmp_path / f"{i}"))
        assert bench.judge(row) == [], (plan, drill, row)


def bench_args(bench):
    import argparse

    return argparse.Namespace(quick=False, plans=None, drills=",".join(bench.KILL), phases=None, modes="sim")
