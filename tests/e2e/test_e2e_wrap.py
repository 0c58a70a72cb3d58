"""The device's u32 microsecond counter wraps every 71.6 min; the host must not notice."""

import asyncio

import numpy as np
import pytest

from dyno.acquisition.poller import Poller
from dyno.acquisition.reader import make_reader
from dyno.acquisition.rpm import rpm_per_period
from dyno.session.root import RunSpec, run_test
from dyno.clock import run
from dyno.protocol import v1
from dyno.runlog.reader import load_run
from dyno.runlog.writer import RunWriter
from dyno.sim.rig import SimRig
from dyno.transports.base import I2CTransport

from .conftest import IDEAL, tare_error  # perfect knowledge: this test checks the statistics alone

WRAP_US = 1 << 32


def test_full_test_across_the_wrap(tmp_path):
    """A complete test whose device clock wraps 60 s in: points as good as ever."""
    # perfect knowledge (--sim-ideal): this checks the timestamps across the wrap, so only noise may differ
    result = run_test(RunSpec(sim=True, seed=5, out_dir=tmp_path / "w", clock_offset_us=WRAP_US - 60_000_000,
                                 sim_params=IDEAL))
    assert result["state"] == "done"
    assert len(result["points"]) >= 15
    # the tare (one zero that every point shares) judged on its own bound, its error taken out of each point
    assert abs(result["torque_tare"]["zero_nm"]) <= 2.6 * result["torque_tare"]["u_nm"], result["torque_tare"]
    for p in result["points"]:
        assert abs(p["efficiency"] - p["efficiency_true"] - tare_error(result, p)) <= 0.005


@pytest.mark.slow
def test_72_minute_soak_crosses_the_wrap_without_a_glitch(tmp_path):
    """72.5 simulated minutes at a steady load through the whole acquisition path and the run log."""
    duration_s = 72.5 * 60

    async def soak():
        loop = asyncio.get_running_loop()
        rig = SimRig(loop.time, seed=7)
        reader = make_reader("v2", I2CTransport(rig.bus, 0x03))
        poller = Poller(reader, poll_hz=100.0)
        writer = RunWriter(tmp_path / "soak", {"mode": "soak"})
        poller.listeners.append(writer.events)
        m = rig.model
        m.engine_enabled, m.throttle_frac = True, 1.0
        rig.start_engine()
        task = asyncio.create_task(poller.run())
        await asyncio.sleep(3.0)
        m.actuator_dir = +1  # load the brake a little, then hold it
        await asyncio.sleep(1.2)
        m.actuator_dir = 0
        await asyncio.sleep(duration_s)
        poller.stop()
        await task
        writer.close("success")
        return rig, reader, poller

    rig, reader, poller = run(soak(), virtual=True)
    s = poller.streams
    assert reader.events_lost == 0 and sum(reader.stats.rejected.values()) == 0
    # every event the device queued arrived exactly once
    assert sum(s.counts().values()) == rig.firmware.events_generated
    # the device counter really wrapped, and the host's times ran on monotonically past 2**32
    assert rig.firmware.device_us(rig.model.t_s) < 1_000_000_000
    for ch in (v1.CH_PRIMARY, v1.CH_SECONDARY):
        t = np.frombuffer(s.edges[ch], dtype=np.int64)
        assert t[-1] > WRAP_US and np.all(np.diff(t) > 0)
        t_end, rpm = rpm_per_period(t[t > t[0] + 30_000_000])  # after the load step has settled
        med = np.median(rpm)
        assert np.max(np.abs(rpm / med - 1)) < 0.08, "an rpm glitch"
        around = (t_end > WRAP_US - 2_000_000) & (t_end < WRAP_US + 2_000_000)
        assert around.sum() > 50 and np.max(np.abs(rpm[around] / med - 1)) < 0.05
    ta = np.frombuffer(s.adc_t, dtype=np.int64)
    codes = np.frombuffer(s.adc_code, dtype=np.uint16).astype(float)
    assert np.all(np.diff(ta) > 0)
    keep = ta > ta[0] + 30_000_000
    ta, codes = ta[keep], codes[keep]
    bins = (ta - ta[0]) // 1_000_000
    means = np.bincount(bins, codes) / np.bincount(bins)
    assert np.max(np.abs(np.diff(means))) < 8 * np.std(np.diff(means)) + 1, "a torque glitch"
    # the run log on disk holds the same streams
    disk = load_run(tmp_path / "soak").streams
    assert disk.counts() == s.counts()
    assert disk.edges[1][-1] == s.edges[1][-1]
