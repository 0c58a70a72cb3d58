"""The simulated rig's CVT parts are not their labels (``--sim-tune-deviation REL``).

A team fits "a 228 g flyweight set" or "a 950 N / 18.2 N/mm spring"; the part on the rig weighs or
pushes a little differently. Each part's true value here is its label times ``1 + d``, ``d`` uniform
in ``[-REL, REL]``:

* flyweight set: the weights' body mass (``mass_each_kg`` without its tuning washers); washers added to
  a body (``washer_mass_each_kg``) are weighed parts, within ``WASHER_REL`` of their label, so a body
  with washers is the same body, keeping its deviation;
* primary spring: ``preload_n`` and ``rate_n_per_m`` (independent draws);
* secondary spring: ``preload_n`` and ``rate_n_per_m`` (independent draws);
* helix: ``angle_from_axis_deg`` (Sorge's delta).

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
    ("flyweights", "flyweights", ("count", "mass_each_kg", "sheave_travel_m", "radius_m"), ("mass_each_kg",)),
    ("primary_spring", "primary_spring", ("preload_n", "rate_n_per_m"), ("preload_n", "rate_n_per_m")),
    # (not its torsion preload: that is the position the spring is clocked to, a setting, not the spring)
    ("secondary_spring", "secondary_spring",
     ("preload_n", "rate_n_per_m", "torsion_rate_nm_per_rad"), ("preload_n", "rate_n_per_m")),
    ("helix", "helix", ("angle_from_axis_deg", "radius_m"), ("angle_from_axis_deg",)),
)
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


def _draws(world_seed: int, key: str, n: int, rel: float) -> np.ndarray:
    ss = np.random.SeedSequence([int(world_seed), _STREAM, zlib.crc32(key.encode())])
    return np.random.default_rng(ss).uniform(-rel, rel, n)


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
        if washers:  # the body is the part; its washers are weighed additions
            body = dataclasses.replace(obj, mass_each_kg=obj.mass_each_kg - washers, washer_mass_each_kg=0.0)
            key = part_key(kind, body, ident)
            (d_body,) = _draws(world_seed, key, 1, rel)
            (d_w,) = _draws(world_seed, f"washers:{washers:.6g}", 1, WASHER_REL)
            label = float(obj.mass_each_kg)
            true = (label - washers) * (1.0 + float(d_body)) + washers * (1.0 + float(d_w))
            changes[f"{attr}.mass_each_kg"] = true
            record.append({"kind": kind, "key": key, "washer_mass_each_kg": washers,
                           "mass_each_kg": {"label": label, "true": true, "deviation_rel": true / label - 1.0,
                                            "body_deviation_rel": float(d_body)}})
            continue
        key = part_key(kind, obj, ident)
        d = _draws(world_seed, key, len(fields), rel)
        entry = {"kind": kind, "key": key}
        for f, dv in zip(fields, d):
            label = float(getattr(obj, f))
            changes[f"{attr}.{f}"] = label * (1.0 + float(dv))
            entry[f] = {"label": label, "true": label * (1.0 + float(dv)), "deviation_rel": float(dv)}
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
