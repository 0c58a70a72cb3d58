"""rig.toml ``[driveline]``: the bound on the loss between the CVT's secondary and the torque gauge.

Split from :mod:`dyno.rigconfig` (which validates the rest of the file with the same reader).

The gauge reads the torque after the secondary's bearings, the 32/61 t roller chain and the brake
shaft's bearings (hardware/README.md), so the CVT's own output is the reading *plus* their loss: a
loss only ever lowers the reading.  Without a coast-down's ``driven_loss.json`` measuring it, each point's
interval carries it as a one-sided term (:mod:`dyno.analysis.systematic`), from ``loss_max_frac``, the
largest fraction of the secondary's power it can take.

Default 0.04, its basis: a lubricated, tensioned #40/#428 roller chain transmits 97…99 % (1…3 % lost:
manufacturers' catalogues, ANSI/ISO roller-chain practice) and each of the two bearing pairs (deep-groove
ball, sealed) takes 0.1…0.5 % at these speeds and loads; together 1.2…4 %, the upper end taken as the
bound (a dry or slack chain loses more: measure it with the coast-down plan).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping


@dataclass(frozen=True)
class DrivelineConfig:
    loss_max_frac: float = 0.04  # chain 1-3 % + two bearing pairs 0.1-0.5 % each (module docstring)


def driveline_table(r, data: Mapping) -> DrivelineConfig:
    t = data.get("driveline", {})
    if not isinstance(t, Mapping):
        raise r.err("driveline", f"expected a table [driveline], got {type(t).__name__}")
    r.no_extra(t, {"loss_max_frac"}, "driveline.")
    return DrivelineConfig(loss_max_frac=r.number(t, "loss_max_frac", "driveline.", lo=0.0, hi=0.3, required=False,
                                                  default=DrivelineConfig.loss_max_frac))
