"""rig.toml ``[inertia]``: the rig's rotating inertias, one source for the I·alpha correction of sweeps and
ramps and the coast-down's driven side; older files' ``[driven]`` inertia keys are mapped onto it.

Split from :mod:`dyno.rig.config` (which validates the rest of the file with the same reader).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping


@dataclass(frozen=True)
class InertiaConfig:
    """Rotating inertias for the I·alpha correction of sweeps and ramps (docs/control.md).

    ``engine_kg_m2``: crank, flywheel and primary pulley (the map's torque minus ``J alpha`` enters the
    CVT).  ``secondary_kg_m2``: secondary pulley, shaft and drive sprocket, the part *upstream* of the
    torque gauge (the gauge already reads the brake shaft's own inertia torque).  ``beyond_gauge_kg_m2``:
    61 t gear, brake shaft and rotor referred to the secondary (x g^2).  The coast-down decelerates both:
    :attr:`driven_kg_m2`, with ``driven_rel_unc`` its relative uncertainty (1 sigma).  One source of truth:
    the old ``[driven]`` inertia keys are mapped here (:func:`inertia_table`)."""

    engine_kg_m2: float = 0.045
    secondary_kg_m2: float = 0.013
    beyond_gauge_kg_m2: float = 0.0121
    driven_rel_unc: float = 0.03

    @property
    def driven_kg_m2(self) -> float:
        """The whole driven side referred to the secondary (what the coast-down decelerates)."""
        return self.secondary_kg_m2 + self.beyond_gauge_kg_m2


#: [driven] keys of older rig files, now in [inertia] (old name -> new name; inertia_kg_m2 is derived)
DRIVEN_INERTIA_KEYS = {"inertia_beyond_gauge_kg_m2": "beyond_gauge_kg_m2", "inertia_rel_unc": "driven_rel_unc",
                       "inertia_kg_m2": None}


def inertia_table(r, data: Mapping) -> tuple[InertiaConfig, tuple]:
    """``[inertia]``, with the old ``[driven]`` inertia keys mapped onto it (a deprecation line each).

    An old file said the driven side's inertia twice: ``[driven] inertia_kg_m2`` (the whole) beside
    ``[inertia] secondary_kg_m2`` (its part upstream of the gauge) and ``[driven] inertia_beyond_gauge_kg_m2``
    (the rest).  The whole is now derived; an old total is kept only if it agrees with the parts, or, when
    the file does not give ``secondary_kg_m2``, it sets it (total - beyond)."""
    t = data.get("inertia", {})
    if not isinstance(t, Mapping):
        raise r.err("inertia", f"expected a table [inertia], got {type(t).__name__}")
    names = {"engine_kg_m2": 10.0, "secondary_kg_m2": 10.0, "beyond_gauge_kg_m2": 10.0, "driven_rel_unc": 0.5}
    r.no_extra(t, set(names), "inertia.")
    old = data.get("driven", {})
    vals = {k: r.number(t, k, "inertia.", lo=0.0, hi=hi, required=False, default=getattr(InertiaConfig, k))
            for k, hi in names.items()}
    notes = []
    for key, new in DRIVEN_INERTIA_KEYS.items():
        if key not in old or new is None:
            continue
        v = r.number(old, key, "driven.", lo=0.0, hi=names[new])
        if new in t and abs(v - vals[new]) > 1e-9 * max(1.0, abs(v)):
            raise r.err(f"driven.{key}", f"deprecated and different from inertia.{new} ({vals[new]}): keep one")
        vals[new] = v
        notes.append(f"[driven] {key} is deprecated: it is [inertia] {new} now (mapped)")
    if "inertia_kg_m2" in old:
        total = r.number(old, "inertia_kg_m2", "driven.", lo=1e-4, hi=10.0)
        parts = vals["secondary_kg_m2"] + vals["beyond_gauge_kg_m2"]
        if "secondary_kg_m2" not in t and total >= vals["beyond_gauge_kg_m2"]:
            vals["secondary_kg_m2"] = total - vals["beyond_gauge_kg_m2"]
            notes.append(f"[driven] inertia_kg_m2 is deprecated: the driven side is [inertia] secondary_kg_m2 + "
                         f"beyond_gauge_kg_m2 now (secondary_kg_m2 = {vals['secondary_kg_m2']:g} mapped from it)")
        elif abs(total - parts) <= 0.005 * total:
            notes.append(f"[driven] inertia_kg_m2 is deprecated: the driven side is [inertia] secondary_kg_m2 + "
                         f"beyond_gauge_kg_m2 = {parts:g} now (remove it)")
        else:
            raise r.err("driven.inertia_kg_m2", f"deprecated and != [inertia] secondary_kg_m2 + beyond_gauge_kg_m2 "
                                                f"({parts:g}), got {total:g}: remove it, set the parts")
    return InertiaConfig(**vals), tuple(f"{r.path}: {n}" for n in notes)
