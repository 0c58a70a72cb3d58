"""Drill ``pi-freeze``: the Pi stops dead, pins frozen at their levels; the Nano and the wiring make the rig safe.

Issue 37's must-shows: the record names who cut the engine (``outputs.engine_cut_by`` "nano"), the drill's
``latency_s`` (freeze -> the kill chain opening, as the physics sees it) is within the heartbeat timeout +
0.1 s, the pads are off the rotor within the release bound through K3, and the run directory written up to
the freeze replays; through the real-rig output code (``--mock-pins``) too, and with the engine heading for
over-speed while the Pi is frozen.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from dyno.session.root import RunSpec, run_test
from dyno.cli.run_cmd import exit_code
from dyno.session.drills import parse_drill
from dyno.errors import ConfigError
from dyno.runlog.replay import replay
from dyno.runlog.reader import load_run

from .conftest import QUICK_PLAN, drill_as_the_user_runs_it

REPO = Path(__file__).resolve().parents[2]
TIMEOUT_S = 0.2  # hardware/rig.toml [limits] supervisor_timeout_s


def _run(tmp_path, drills, *, mock_pins=False, name="run"):
    held = {}
    r = run_test(RunSpec(sim=True, seed=3, out_dir=tmp_path / name, plan=QUICK_PLAN,
                            drills=[parse_drill(d) for d in drills], setup=lambda ctx: held.update(ctx=ctx),
                            mock_pins=mock_pins))
    return r, held["ctx"]


def _freeze_record(r):
    return next(d for d in r["drills"] if d["name"] == "pi-freeze")


def _assert_nano_made_it_safe(r, ctx):
    assert r["state"] == "aborted" and exit_code(r) == 3
    rec = _freeze_record(r)
    model = ctx.sim.model
    # the physics: the kill chain opened by the Nano's output, within the timeout (+0.1 s) of the freeze
    t_cut, by = model.engine_cut(rec["onset_s"])
    assert by == "nano" and rec["engine_cut_by"] == "nano" and r["outputs"]["engine_cut_by"] == "nano"
    assert 0.0 < t_cut - rec["onset_s"] <= TIMEOUT_S + 0.1
    assert rec["latency_s"] == pytest.approx(t_cut - rec["onset_s"]) and rec["latency_within_bound"]
    # the Pi was frozen all that time: its own safe state came only after it resumed
    assert r["aborts"][0]["safe_commanded_s"] >= rec["resumed_s"] - 1e-9
    assert r["aborts"][0]["engine_cut_at_s"] == rec["engine_cut_at_s"] == r["outputs"]["engine_cut_at_s"]
    # K3 (fitted in the shipped rig file) released the brake by wiring while the Pi was still frozen
    assert rec["k3_fitted"] and rec["pads_off_within_bound"], rec
    assert rec["pads_off_at_s"] < rec["resumed_s"]
    assert r["outputs"]["pads_off_rotor"] and r["rig_safe"]
    return rec


def test_pi_freeze_while_loaded_the_nano_cuts_and_k3_releases(tmp_path):
    r, ctx = _run(tmp_path, ["pi-freeze@loaded+2"])
    _assert_nano_made_it_safe(r, ctx)
    assert r["supervisor"]["drops"][0]["cause"] == "heartbeat"
    assert r["aborts"][0]["cause"] == "nano_heartbeat"
    # nothing recorded is lost: every point in the JSON is in the run directory, which replays
    run = load_run(r["run_dir"])
    assert len(run.docs("point")) == len(r["points"])
    assert replay(r["run_dir"])["points"] is not None


def test_pi_freeze_through_the_real_rig_output_code(tmp_path):
    r, ctx = _run(tmp_path, ["pi-freeze@loaded+2"], mock_pins=True)
    _assert_nano_made_it_safe(r, ctx)
    # the driver's own verdict agrees with the physics at the end
    assert r["outputs"]["driver_agrees"], r["outputs"].get("driver_disagreement")


def test_pi_freeze_with_the_engine_heading_for_overspeed(tmp_path):
    """The governor fails as the Pi freezes: the throttle stays wide open (the servo's pin frozen) and only the
    Nano is watching; it cuts on its own over-speed check or its heartbeat, whichever comes first."""
    r, ctx = _run(tmp_path, ["overspeed@loaded+2", "pi-freeze@loaded+2"])
    rec = _assert_nano_made_it_safe(r, ctx)
    truth = ctx.sim.truth
    t_cut = rec["engine_cut_at_s"]
    lim = ctx.controller.limits
    # the true primary speed never got far past the limit: the Nano acted on the edges it timestamps
    peak = max(rp for t, rp in zip(truth.t, truth.rp) if rec["onset_s"] <= t <= t_cut + 0.5) if truth.t else 0.0
    assert peak < lim.overspeed_primary_rpm * 1.15, peak
    assert r["supervisor"]["drops"][0]["cause"] in ("overspeed_primary", "heartbeat")


def test_a_freeze_within_the_heartbeat_is_no_hazard(tmp_path):
    """0.1 s < the 0.2 s timeout: the host is back in time, nothing is cut, the run goes on; the record says
    the hazard did not arise (not a missed bound)."""
    r, ctx = _run(tmp_path, ["pi-freeze:0.1@loaded+2"])
    rec = _freeze_record(r)
    assert r["state"] == "done" and not rec["hazard_arose"] and "heartbeat" in rec["hazard_note"]
    assert r["supervisor"]["drops"] == [] and ctx.sim.model.engine_cut(rec["onset_s"])[1] == "pi"  # (the end)


def test_pi_freeze_argument_is_checked():
    assert parse_drill("pi-freeze:2.5@loaded+1").arg == "2.5"
    for bad in ("pi-freeze:0@1", "pi-freeze:x@1", "pi-freeze:700@1"):
        with pytest.raises(ConfigError, match="pi-freeze"):
            parse_drill(bad)


def test_pi_freeze_as_the_user_runs_it(tmp_path):
    """The command itself: exit 3, the JSON's verdict, and ``dyno replay`` of the run directory exits 0."""
    r = drill_as_the_user_runs_it(tmp_path / "cli", "--drill", "pi-freeze@loaded+2")  # (replayed: nothing lost)
    assert r["outputs"]["engine_cut_by"] == "nano"
    rec = _freeze_record(r)
    assert rec["latency_s"] <= TIMEOUT_S + 0.1 and rec["pads_off_within_bound"]


def test_pi_freeze_with_the_end_switch_no_false_rig_fault(tmp_path):
    """K3 released the brake by wiring while the Pi was frozen: when the Pi's code resumes, its estimate says
    the brake is still out while the end switch is closed. That is K3's doing, not a stuck switch: no rig fault
    (a fault would refuse every re-arm until ``dyno doctor --toggle``), and the release is still confirmed."""
    text = (REPO / "hardware" / "rig.toml").read_text()
    assert "\nestop_input = 22" in text  # the shipped rig declares both safety inputs
    assert "\nbrake_released_input = 27" in text and "\nbrake_hold_relay = true" in text
    rig = tmp_path / "wired.toml"
    rig.write_text(text)
    held = {}
    r = run_test(RunSpec(sim=True, seed=3, out_dir=tmp_path / "run", plan=QUICK_PLAN, rig_path=rig,
                            drills=[parse_drill("pi-freeze@loaded+2")], setup=lambda ctx: held.update(ctx=ctx),
                            mock_pins=True))
    _assert_nano_made_it_safe(r, held["ctx"])
    assert r["rig_faults"] == [], r["rig_faults"]
    assert r["outputs"]["driver_agrees"] and r["outputs"]["driver_release_basis"] == "end_of_travel"


def test_pi_freeze_is_refused_in_a_live_session():
    """A live session's watchdog is a real thread: the drill cannot freeze it; one line, exit 2, before the
    screen is taken over."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    p = subprocess.run([sys.executable, "-m", "dyno", "ui", "--sim", "--drill", "pi-freeze@5"], capture_output=True,
                       text=True, env=env, timeout=120)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    (line,) = p.stderr.strip().splitlines()
    assert "--drill" in line and "pi-freeze" in line and "dyno run --sim" in line
