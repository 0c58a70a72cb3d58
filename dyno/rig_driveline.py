"""rig.toml ``[driveline]``: the bound on the loss between the CVT's secondary and the torque gauge.

Split from :mod:`dyno.rigconfig` (which validates the rest of the file with the same reader).

The gauge reads the torque after the secondary's bearings, the 32/61 t roller chain and the brake
shaft's bearings (hardware/README.md), so the CVT's own output is the reading *plus* their loss: a
loss only ever lowers the reading.  Without a coast-down's ``driven_loss.json`` measuring it, each point's
interval carries it as a one-sided term (:mod:`dyno.analysis.systematic`) up to
``L_max = loss_max_frac + drag_max_nm / |T_s|``, a fraction of the gauge's reading:

* ``loss_max_frac`` 0.03, the chain's load-proportional mesh loss: a lubricated, tensioned #40/#428 roller
  chain transmits 97…99 % (chain makers' design guides, ANSI B29 practice);
* ``drag_max_nm`` 0.25 N·m at the secondary, the bearings' and seals' drag, which does not scale with the
  load: sealed deep-groove bearings on ~25 mm shafts drag 0.02…0.06 N·m each at these speeds (bearing
  makers' friction models: rolling, viscous and seal parts), four of them, the brake shaft's referred
  through the 32/61 ratio.

So ~4 % at 30 N·m and ~7 % at 6 N·m (light load, high speed).  A dry or slack chain loses more: measure it
with the coast-down plan.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping


@dataclass(frozen=True)
class DrivelineConfig:
    loss_max_frac: float = 0.03  # the chain's mesh loss, a share of the load (module docstring)
    drag_max_nm: float = 0.25  # the bearings' and seals' drag at the secondary, N·m (module docstring)


def driveline_table(r, data: Mapping) -> DrivelineConfig:
    t = data.get("driveline", {})
    if not isinstance(t, Mapping):
        raise r.err("driveline", f"expected a table [driveline], got {type(t).__name__}")
    r.no_extra(t, {"loss_max_frac", "drag_max_nm"}, "driveline.")
    return DrivelineConfig(loss_max_frac=r.number(t, "loss_max_frac", "driveline.", lo=0.0, hi=0.3, required=False,
                                                  default=DrivelineConfig.loss_max_frac),
                           drag_max_nm=r.number(t, "drag_max_nm", "driveline.", lo=0.0, hi=5.0, required=False,
                                                default=DrivelineConfig.drag_max_nm))
