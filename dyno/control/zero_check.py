"""Reading the torque zero at rest on the rig (before GO, after the last point).

The pure part is :mod:`dyno.analysis.zero_check`; this module only waits for the
shafts to be at rest and takes the ADC window.  Before GO the engine idles below
engagement, so the secondary is at rest; after the test the rig is in its safe state
(engine cut, brake releasing) and the secondary coasts to rest first.
"""

from __future__ import annotations

import asyncio
import math

from dyno.analysis.zero_check import zero_reading
from dyno.protocol import v1


def zero_config(ctrl):
    """rig.toml's [torque_zero] (its defaults where the rig has none)."""
    from dyno.rig.config import TorqueZeroConfig

    return getattr(getattr(ctrl, "rig", None), "torque_zero", None) or TorqueZeroConfig()


async def _sleep(ctrl, dt_s: float) -> None:
    # after the test the controller's _sleep still works (it only ticks the outputs)
    await asyncio.sleep(dt_s)
    ctrl.act.tick(ctrl.host_now())


async def read_zero(ctrl, *, wait_rest_s: float = 0.0) -> dict:
    """Mean torque over ``read_s`` with the secondary at rest (waiting up to ``wait_rest_s`` for it)."""
    cfg = zero_config(ctrl)
    poller = ctrl.poller
    t_wait = ctrl.host_now()
    # with an engine-side input torque channel the zero after the test waits for the crank too: a
    # coasting engine's friction reacts on its cradle (before GO it idles unloaded: no reaction)
    crank = wait_rest_s > 0 and getattr(ctrl, "input_channel", None) is not None
    while poller.rpm(v1.CH_SECONDARY) > 0.0 or (crank and poller.rpm(v1.CH_PRIMARY) > 0.0):
        if ctrl.host_now() - t_wait >= wait_rest_s:
            why = f"the secondary turns ({poller.rpm(v1.CH_SECONDARY):.0f} rpm): not at rest"
            if crank and poller.rpm(v1.CH_PRIMARY) > 0.0:
                why = f"the engine turns ({poller.rpm(v1.CH_PRIMARY):.0f} rpm): not at rest"
            return {"torque_nm": math.nan, "ci95_nm": math.nan, "why": why}
        await _sleep(ctrl, 0.1)
    h0, d0 = ctrl.host_now(), poller.device_now_us()
    await _sleep(ctrl, cfg.read_s)
    h1, d1 = ctrl.host_now(), poller.device_now_us()
    if d0 is None or d1 is None:
        return {"torque_nm": math.nan, "ci95_nm": math.nan, "why": "no device time"}
    if poller.rpm(v1.CH_SECONDARY) > 0.0:
        return {"torque_nm": math.nan, "ci95_nm": math.nan, "why": "the secondary started turning during the read"}
    _, codes, status = poller.streams.adc_window(d0, d1)
    out = zero_reading(codes, status, ctrl.calibration)
    out.update(t_mid_s=0.5 * (h0 + h1), t_start_us=int(d0), t_end_us=int(d1))
    return out


async def after_test(ctrl, *, wait_rest_s: float = 30.0) -> dict:
    """After the last point: the zero at rest, the drift since GO, recorded with the run."""
    from dyno.analysis.zero_check import drift_check

    after = await read_zero(ctrl, wait_rest_s=wait_rest_s)
    before = getattr(ctrl, "zero_before", None) or {"torque_nm": math.nan, "ci95_nm": math.nan,
                                                    "why": "not read"}
    check = drift_check(before, after, zero_config(ctrl).drift_max_nm)
    check["correct"] = zero_config(ctrl).correct
    ctrl.set_zero_check(check)
    ctrl.plan_context.log("torque_zero", **check)
    channel = getattr(ctrl, "input_channel", None)
    if channel is not None:  # the engine-side input channel (issue 27): its zero over the same two windows
        from dyno.analysis.input_torque import input_zero_check

        input_check = input_zero_check(ctrl.poller.streams, check, channel)
        ctrl.set_zero_check(check, input_check)
        ctrl.plan_context.log("torque_zero_input", **input_check)
    return check
