"""Firmware in the loop (issue 55): the Nano's real ELF in simavr between the simulated rig's physics and the host
(``dyno run --sim --firmware-elf``).  Judged on the physics: every sensor event the physics made reaches the host
through the ELF, the ELF's run-enable is what cuts the simulated engine, and a run through the ELF measures what
the same seed measures through the Python emulation of the firmware."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.fw_build import sim_elf

SEED = 3
#: the shipped plan and seed the suite's --plans check runs (the cheapest through the ELF:
#: docs/measurements/2026-12-06-fil-plans.md)
CHEAP_PLAN, CHEAP_SEED = "coast-down", 1


def _fil_run(tmp_path, **kw):
    """An in-process run; its context, and the Nano's INFO frame read as the run's rig closes (its counters)."""
    from dyno.session.root import RunSpec, run_test

    seen = {}

    def setup(ctx):
        seen["ctx"] = ctx
        close = ctx.sim.close

        def read_info_then_close():
            seen["info"] = ctx.poller.reader.read_info()
            close()
        ctx.sim.close = read_info_then_close

    result = run_test(RunSpec(sim=True, seed=SEED, out_dir=tmp_path / "run", setup=setup, **kw))
    return result, seen["ctx"], seen["info"]


@pytest.mark.quick
def test_fil_short_run_hands_every_physics_event_to_the_host_and_the_elf_holds_the_kill_chain(tmp_path):
    elf = sim_elf()
    result, ctx, info = _fil_run(tmp_path, firmware_elf=elf, max_sim_s=18.0)  # (the ignition closes ~9 s in: the start-up release)
    fw = ctx.sim.firmware
    assert result["firmware"]["elf"] == str(elf) and not result["firmware"]["harness"]["crashed"]
    assert result["firmware"]["late_events"] == 0 and result["firmware"]["harness"]["dropped_events"] == 0
    assert result["link"]["frames_lost"] == 0 and result["events_lost"] == 0, result["link"]
    # lossless against the physics: every Hall edge and conversion the physics made reached the host, or was
    # rejected by the firmware's own lock-out (the physics' ignition bounce: counted by the ELF, read in its INFO),
    # up to the last poll (the tail after it is still in the Nano's ring when the run stops)
    counts = ctx.poller.streams.counts()
    made = fw.events_by_channel
    assert made["primary"] > 100 and made["secondary"] > 100, made  # the engine ran and the CVT engaged
    rejected = {ch: lock + glitch for ch, lock, glitch in zip(("primary", "secondary"), info.lockout_rejected,
                                                                info.glitch_rejected)}
    for key, channel, tail in (("primary_edges", "primary", 2), ("secondary_edges", "secondary", 2),
                               ("adc_samples", "adc", 6)):
        seen = counts[key] + rejected.get(channel, 0)
        assert made[channel] - tail <= seen <= made[channel], (key, counts, made, rejected)
    # the ELF's run-enable closed the chain (the engine could only start once it did) and the run's end cut it
    on_log = [(t, on) for t, on, _ in fw.run_enable_log]
    assert on_log and on_log[0][1] is True, on_log
    assert ctx.sim.model.engine_cut(0.0) is not None  # the timeout's safe state: the chain opened


@pytest.mark.quick
def test_fil_a_shaft_speeding_up_from_a_crawl_gives_a_pulse_per_edge():
    """A real edge is a pulse of its own however much sooner than the last period it comes (a secondary turning
    once in 2 s, then engaging: 0.3 s, 0.1 s, 0.02 s); only an edge within the physics' bounce window of a pulse is
    that pulse's bounce.  (The old rule, a quarter of the last period, made those real edges 20 us spikes that the
    firmware rejects: the engagement plan aborted through the ELF, "secondary stopped under load".)"""
    from dyno.sim.elf_firmware import BOUNCE_HIGH_US, MAX_PULSE_US, ElfFirmware

    fw = ElfFirmware(sim_elf())
    try:
        for t_s in (1.0, 3.0, 3.3, 3.4, 3.42, 3.4203):  # (the last: 0.3 ms after its edge, in its pulse)
            fw.capture("secondary", t_s)
        pending = [item.split(":") for item in fw._pending]
    finally:
        fw.close()
    assert [p[0] for p in pending] == ["h1"] * 5 + ["b1"], pending
    assert all(float(p[2]) > BOUNCE_HIGH_US for p in pending[:5]), pending  # pulses, not spikes
    assert float(pending[4][2]) == MAX_PULSE_US  # (5 % of the period before it, 0.1 s: capped)


@pytest.fixture(scope="module")
def fil_thesis_step(tmp_path_factory):
    """The issue's command as a real process: ``dyno run --sim --firmware-elf ELF --headless --json --plan
    thesis-step --seed S``."""
    elf = sim_elf()
    out = tmp_path_factory.mktemp("fil") / "run"
    proc = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--firmware-elf", str(elf), "--headless",
                           "--json", "--plan", "thesis-step", "--seed", str(SEED), "--out", str(out)],
                          capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout), elf


def test_fil_thesis_step_reaches_done_through_the_real_firmware(fil_thesis_step):
    result, elf = fil_thesis_step
    assert result["state"] == "done" and len(result["points"]) >= 10, (result["state"], result["reason"])
    assert result["link"]["frames_lost"] == 0 and result["events_lost"] == 0
    assert result["firmware"]["elf"] == str(elf) and not result["firmware"]["harness"]["crashed"]
    assert result["firmware"]["late_events"] == 0
    assert result["rig_safe"] and result["outputs"]["pads_off_rotor"]


def test_fil_and_the_emulated_firmware_measure_the_same_rig(fil_thesis_step, tmp_path):
    """The same seed through the ELF and through dyno/sim/device.py: the points' count within 1, and at >= 90 %
    of the points the efficiencies within sqrt(CI95_a^2 + CI95_b^2), each FIL point paired with the emulated run's
    point at the nearest secondary speed (the same operating point; one world, so the systematic terms are common
    and only the random part may differ)."""
    from dyno.control.planfile import load_plan_file, shipped_plans

    fil, _ = fil_thesis_step
    emu, _, _ = _fil_run(tmp_path, plan=load_plan_file(shipped_plans()["thesis-step"]))
    a, b = fil["points"], emu["points"]
    assert abs(len(a) - len(b)) <= 1, (len(a), len(b))
    pairs = [(pa, min(b, key=lambda pb: abs(pb["rpm_secondary"] - pa["rpm_secondary"]))) for pa in a]
    agree = [abs(pa["efficiency"] - pb["efficiency"]) <= math.hypot(pa["efficiency_ci95"], pb["efficiency_ci95"])
             for pa, pb in pairs]
    assert sum(agree) >= 0.9 * len(agree), [(pa["efficiency"], pb["efficiency"]) for pa, pb in pairs]


def test_fil_pi_freeze_is_cut_by_the_real_firmwares_run_enable(tmp_path):
    """``--drill pi-freeze@loaded+2`` through the ELF: the frozen host stops polling, the ELF's own supervisor drops
    D7 and the physics' kill chain opens on it (engine_cut_by "nano", from the physics), within the drill's bound;
    K3 takes the pads off the rotor; exit 3."""
    elf = sim_elf()
    proc = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--firmware-elf", str(elf), "--headless",
                           "--json", "--plan", "thesis-step", "--seed", str(SEED), "--drill", "pi-freeze@loaded+2",
                           "--out", str(tmp_path / "run")], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 3, proc.stderr[-2000:]
    result = json.loads(proc.stdout)
    (drill,) = result["drills"]
    assert drill["engine_cut_by"] == "nano" and result["outputs"]["engine_cut_by"] == "nano", drill
    assert drill["latency_within_bound"] and drill["latency_s"] <= drill["latency_bound_s"], drill
    assert drill["latency_s"] >= drill["supervisor_timeout_s"] - 0.01, drill  # (the ELF's timeout, not earlier)
    assert result["outputs"]["pads_off_rotor"] and drill["pads_off_within_bound"], result["outputs"]
    assert result["firmware"]["run_enable_changes"] >= 2 and result["firmware"]["late_events"] == 0
    assert result["link"]["frames_lost"] == 0


@pytest.mark.quick
def test_fil_bad_input_is_one_line_and_exit_2(tmp_path):
    """A missing ELF, a serial rig file (the harness's master is I2C), the ELF on the real rig: one line naming the
    file or field, exit 2, nothing written."""
    from tests.bad_input import one_line_failures, snapshot

    repo = sim_elf().parents[2]
    serial_rig = repo / "hardware" / "rig-input-torque.toml"
    assert 'transport = "serial"' in serial_rig.read_text()

    def run(*argv):
        return subprocess.run([sys.executable, "-m", "dyno", *argv], capture_output=True, text=True, timeout=120,
                              cwd=tmp_path)

    own_rig = tmp_path / "rig.toml"  # (a rig of one's own: the shipped file is never taken for real hardware)
    own_rig.write_text((repo / "hardware" / "rig.toml").read_text())
    before = snapshot(tmp_path)
    cases = [("no such ELF", ["run", "--sim", "--headless", "--firmware-elf", str(tmp_path / "none.elf")],
              ["none.elf", "--firmware-elf"]),
             ("a serial rig file", ["run", "--sim", "--headless", "--rig", str(serial_rig), "--firmware-elf",
                                    str(sim_elf())], ["rig-input-torque.toml", "transport"]),
             ("the UI off the sim", ["ui", "--rig", str(own_rig), "--firmware-elf", str(sim_elf())],
              "--firmware-elf"),
             ("the wizard off the sim", ["calibrate", "--rig", str(own_rig), "--firmware-elf", str(sim_elf())],
              "--firmware-elf"),
             ("the wizard, no such ELF", ["calibrate", "--sim", "--firmware-elf", str(tmp_path / "none.elf")],
              ["none.elf", "--firmware-elf"])]
    assert not one_line_failures(cases, run)
    assert snapshot(tmp_path) == before


@pytest.mark.quick
def test_fil_calibration_fixture_reads_a_hung_mass_through_the_real_firmware():
    """``dyno calibrate --sim --firmware-elf``'s acquisition: the calibration fixture's conversions reach the host
    through the ELF, every one of them up to the last poll, and a hung mass moves the codes by the fixture's true
    gain x torque (the fixture's truth, not the host's calibration)."""
    import asyncio

    import numpy as np

    from dyno.session.calibration import build_calibration, close_calibration

    elf = sim_elf()

    async def main():
        loop = asyncio.get_running_loop()
        # real time, as the wizard runs (simavr keeps up with it several times over; a pace it cannot keep would
        # stall the loop, and the Nano's ring would overflow in the gap, as on a rig whose Pi stalls)
        ctx = build_calibration(sim=True, loop=loop, seed=4, speed=1.0, firmware_elf=elf)
        task = asyncio.create_task(ctx.poller.run())
        try:
            await asyncio.sleep(3.0)  # the tare
            n_tare = ctx.poller.streams.adc_total
            torque_nm = ctx.sim.hang(20.0, 0.25)
            await asyncio.sleep(3.0)  # its settling, and ~2 s at the load
            return ctx, n_tare, torque_nm
        finally:
            ctx.poller.stop()
            await asyncio.gather(task, return_exceptions=True)
            close_calibration(ctx)

    ctx, n_tare, torque_nm = asyncio.run(main())
    fixture, streams, fw = ctx.sim.fixture, ctx.poller.streams, ctx.sim.firmware
    codes = np.asarray(streams.adc_code, dtype=float)
    assert fw.events_by_channel["adc"] - 6 <= streams.adc_total <= fw.events_by_channel["adc"]
    assert fw.late_events == 0 and n_tare > 100 and streams.adc_total > n_tare + 200
    shift = np.median(codes[-100:]) - np.median(codes[n_tare - 100:n_tare])
    expected = fixture.true_counts(torque_nm) - fixture.true_counts(0.0)
    assert abs(shift - expected) < 0.02 * abs(expected) + 5, (shift, expected)
    assert fw._proc.poll() is not None  # the harness ended with the calibration


@pytest.mark.quick
def test_fil_live_session_paces_the_elf_with_the_physics(tmp_path):
    """``dyno ui --sim --speed 2 --firmware-elf``'s session: the ELF runs on the paced clock with the physics (its
    clock is the simulated one: it keeps up with real time several times over), arms its run-enable, the engine
    starts on it and the session reaches ARMED; the harness ends with the session."""
    import asyncio
    import time

    from dyno.control.api import State
    from dyno.ui.session import LiveOptions, LiveSession

    elf = sim_elf()

    async def main():
        s = LiveSession(LiveOptions(sim=True, speed=2.0, seed=5, out_dir=tmp_path / "run", firmware_elf=elf))
        s.start()
        t_end = time.monotonic() + 120
        try:
            while s.controller.state is not State.ARMED and time.monotonic() < t_end:
                await asyncio.sleep(0.05)
            return s, s.controller.state, s.sim_now(), s.sim.model.t_s, s.sim.firmware.t_s
        finally:
            await s.close("test")

    s, state, sim_now_s, model_t_s, elf_t_s = asyncio.run(main())
    fw = s.sim.firmware
    assert state is State.ARMED, s.controller.reason
    assert [on for _, on, _ in fw.run_enable_log][:1] == [True]  # the ELF closed the chain
    # one clock: the ELF's is the physics' (a lockstep cell and a transfer's look-ahead apart at most)
    assert abs(elf_t_s - model_t_s) < 0.02 and model_t_s <= sim_now_s + 0.02, (elf_t_s, model_t_s, sim_now_s)
    assert fw.late_events == 0 and fw._proc.poll() is not None


@pytest.mark.slow
def test_bench_fil_plans_mode_runs_a_shipped_plan_through_the_real_firmware_to_done():
    """``bench/bench_fil.py --plans`` (every shipped plan on two seeds through the ELF: the check behind
    docs/measurements/2026-12-06-fil-plans.md) on one cheap plan and seed: the plan runs with and without the ELF,
    the FIL run reaches done with its output, losing nothing and handing nothing late; exit 0, and its table row
    says so.  (The whole matrix is the bench's, not the suite's: ~15 FIL runs of up to 13 simulated minutes.)"""
    sim_elf()  # (built here; skips, naming what is missing, without the AVR toolchain)
    repo = Path(__file__).resolve().parents[2]
    proc = subprocess.run([sys.executable, str(repo / "bench" / "bench_fil.py"), "--plans", CHEAP_PLAN, "--seeds",
                           str(CHEAP_SEED), "--md"], capture_output=True, text=True, timeout=900, cwd=repo,
                          env={**os.environ, "PYTHONPATH": str(repo)})
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    (row,) = [line for line in proc.stdout.splitlines() if line.startswith(f"| {CHEAP_PLAN} | {CHEAP_SEED} |")]
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2] == "done" and cells[-1] == "ok", row
    assert cells[7].startswith("0 / 0, 0"), row  # frames / events lost, late
