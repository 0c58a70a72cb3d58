"""The simulated rig's CVT parts are not their labels (``--sim-tune-deviation REL``).

A team fits "a 228 g flyweight set" or "a 950 N / 18.2 N/mm spring"; the part on the rig weighs or
pushes a little differently. Each field's true value here is its label times ``1 + d`` (a length: plus
``d``), ``d`` normal with a standard deviation of half its bound ``REL x w`` and cut at that bound, ``w``
the field's share of ``REL`` from its manufacturing norm (:data:`FIELDS`; ``REL`` = 0.1 is the widest
field's +-10 %):

* flyweight set: the body's mass (cast/sintered weights: ~half a spring's spread, ``w`` 0.5) and its
  centre-of-mass radius (an offset of the whole profile, bound ``REL x`` 5 mm: 0.5 mm at 0.1); washers added to
  a body (``washer_mass_each_kg``) are weighed parts, within ``WASHER_REL`` of their label, so a body
  with washers is the same body, keeping its deviation;
* primary and secondary springs: preload (force at a length: DIN EN 15800 grade 2-3, +-5-15 %, ``w`` 1)
  and rate (``w`` 0.7) independently; the secondary's torsion rate (DIN 2194, ``w`` 1);
* helix: its angle (a machined ramp, ~+-0.5 deg: ``w`` 0.15) and its radius (``w`` 0.05).

These are the sim's own spreads, not the advisor's prior (uniform +-tolerance on the mass, preloads,
rates and helix angle): the advisor does not calibrate the profile radius, the torsion rate or the helix
radius at all.

``d`` is drawn from the simulator's own stream keyed by the world seed *and the part* (its kind and
its labelled values), so the same part keeps its deviation on the same rig across runs and tunes,
and a different part, or another rig, gets its own. Nothing here reads the host's files: the labels
are what is physically fitted (the tune the sim is given), the deviation is the sim's secret.

The belt-model efficiency table (``dyno.sim.belt_table``) stays the labelled tune's: a table per true
tune would cost ~90 s per draw; the clamp, the engagement and the shift balance use the true parts.
"""

from __future__ import annotations

import dataclasses
import zlib

import numpy as np

#: (kind, the tune attribute holding the part, the labelled fields that identify it, the deviated fields)
PARTS: tuple[tuple[str, str, tuple[str, ...], tuple[str, ...]], ...] = (
    ("flyweights", "flyweights", ("count", "mass_each_kg", "sheave_travel_m", "radius_m"),
     ("mass_each_kg", "radius_m")),
    ("primary_spring", "primary_spring", ("preload_n", "rate_n_per_m"), ("preload_n", "rate_n_per_m")),
    # (not its torsion preload: that is the position the spring is clocked to, a setting, not the spring)
    ("secondary_spring", "secondary_spring",
     ("preload_n", "rate_n_per_m", "torsion_rate_nm_per_rad"),
     ("preload_n", "rate_n_per_m", "torsion_rate_nm_per_rad")),
    ("helix", "helix", ("angle_from_axis_deg", "radius_m"), ("angle_from_axis_deg", "radius_m")),
)
#: each deviated field's share w of REL (module docstring); the flyweights' radius is an offset of REL x w metres
FIELDS: dict[tuple[str, str], float] = {
    ("flyweights", "mass_each_kg"): 0.5, ("flyweights", "radius_m"): 0.005,
    ("primary_spring", "preload_n"): 1.0, ("primary_spring", "rate_n_per_m"): 0.7,
    ("secondary_spring", "preload_n"): 1.0, ("secondary_spring", "rate_n_per_m"): 0.7,
    ("secondary_spring", "torsion_rate_nm_per_rad"): 1.0,
    ("helix", "angle_from_axis_deg"): 0.15, ("helix", "radius_m"): 0.05,
}
_STREAM = 0x25  # this deviation's stream (the world's draws use 0x24)
#: tuning washers: stamped and weighed parts (a kitchen scale's +-2 %), not a cast body's +-REL
WASHER_REL = 0.02


def part_key(kind: str, obj, fields: tuple[str, ...]) -> str:
    """A part's identity: its kind and labelled values (rounded so a TOML round trip keeps it)."""
    vals = []
    for f in fields:
        v = getattr(obj, f)
        vals.append(",".join(f"{x:.6g}" for x in v) if isinstance(v, tuple) else f"{v:.6g}")
    return kind + ":" + ";".join(vals)


def _draws(world_seed: int, key: str, bounds) -> np.ndarray:
    """Normal draws with sd = bound / 2, cut at +-bound (one per bound)."""
    ss = np.random.SeedSequence([int(world_seed), _STREAM, zlib.crc32(key.encode())])
    b = np.asarray(bounds, dtype=float)
    return np.clip(np.random.default_rng(ss).normal(0.0, 1.0, b.size), -2.0, 2.0) * b / 2.0


def deviate_tune(tune, rel: float, world_seed: int):
    """``(true tune, parts record)``: each part of ``tune`` at its true value on this rig.

    The record lists, per part, its kind, key, and for each deviated field the label, the truth and
    the relative deviation (the sim's truth, for tests and benches; never an input of the host).
    """
    if rel <= 0.0 or tune is None:
        return tune, ()
    changes: dict[str, float] = {}
    record = []
    for kind, attr, ident, fields in PARTS:
        obj = getattr(tune, attr, None)
        if obj is None:
            continue  # e.g. no flyweights on a roller-track tune
        washers = float(getattr(obj, "washer_mass_each_kg", 0.0)) if kind == "flyweights" else 0.0
        # with washers the body is the part (its washers are weighed additions)
        body = dataclasses.replace(obj, mass_each_kg=obj.mass_each_kg - washers, washer_mass_each_kg=0.0) \
            if washers else obj
        key = part_key(kind, body, ident)
        d = _draws(world_seed, key, [rel * FIELDS[(kind, f)] for f in fields])
        entry = {"kind": kind, "key": key}
        for f, dv in zip(fields, (float(v) for v in d)):
            label = getattr(obj, f)
            if kind == "flyweights" and f == "radius_m":  # the casting's centre of mass: an offset in metres
                changes[f"{attr}.{f}"] = tuple(float(r) + dv for r in label)
                entry[f] = {"offset_m": dv}
                continue
            label = float(label)
            if kind == "flyweights" and washers:
                (d_w,) = _draws(world_seed, f"washers:{washers:.6g}", [WASHER_REL])
                true = (label - washers) * (1.0 + dv) + washers * (1.0 + float(d_w))
                entry["washer_mass_each_kg"] = washers
                entry[f] = {"label": label, "true": true, "deviation_rel": true / label - 1.0,
                            "body_deviation_rel": dv}
            else:
                true = label * (1.0 + dv)
                entry[f] = {"label": label, "true": true, "deviation_rel": dv}
            changes[f"{attr}.{f}"] = true
        record.append(entry)
    return tune.with_changes(**changes), tuple(record)


def parts_on_the_rig(tune, params, seed: int, world):
    """``(true tune, world)`` for the rig ``params`` on ``seed``: the world records the parts' truth."""
    rel = getattr(params, "tune_deviation_rel", 0.0)
    if not rel or tune is None:
        return tune, world
    world_seed = int(seed if params.world_seed is None else params.world_seed)
    true, parts = deviate_tune(tune, rel, world_seed)
    return true, dataclasses.replace(world, tune_parts=parts)
