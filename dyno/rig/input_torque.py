"""rig.toml ``[input_torque]``: the optional engine-side torque channel (issue 27; hardware/README.md).

Split from :mod:`dyno.rig.config` (which validates the rest of the file with the same reader).  No table:
no channel, and nothing about a run changes.  With it, the host asks the firmware for the channel at every
boot (docs/protocol.md, "Input torque channel"), every point's efficiency is ``P_out / (T_in ω_p)``
(docs/analysis.md), and the simulated rig has the channel too (``hardware/rig-input-torque.toml``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping


@dataclass(frozen=True)
class InputTorqueConfig:
    sensor: str = "cradle"  # "cradle": load cell on the engine cradle's reaction arm | "inline": rotary sensor
    calibration: str = "calibration/input_torque_calibration.csv"  # its history (dyno calibrate --channel input)
    # the cradle's bearings hold part of the reaction off the load cell: added back (N m), and its
    # standard uncertainty (hardware/README.md: how to check it); 0 / small for an in-line sensor
    bearing_loss_nm: float = 0.0
    bearing_loss_u_nm: float = 0.1


def input_torque_table(r, data: Mapping) -> InputTorqueConfig | None:
    t = data.get("input_torque")
    if t is None:
        return None
    if not isinstance(t, Mapping):
        raise r.err("input_torque", f"expected a table [input_torque], got {type(t).__name__}")
    p = "input_torque."
    r.no_extra(t, {"sensor", "calibration", "bearing_loss_nm", "bearing_loss_u_nm"}, p)
    return InputTorqueConfig(
        sensor=r.string(t, "sensor", p, choices=("cradle", "inline"), required=False, default="cradle"),
        calibration=r.string(t, "calibration", p, required=False, default=InputTorqueConfig.calibration),
        bearing_loss_nm=r.number(t, "bearing_loss_nm", p, lo=0.0, hi=5.0, required=False, default=0.0),
        bearing_loss_u_nm=r.number(t, "bearing_loss_u_nm", p, lo=0.0, hi=5.0, required=False, default=0.1))
