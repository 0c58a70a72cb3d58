"""The belt-model cache's keys: each prediction's inputs and the model's source code, hashed.

A result is stored as one small JSON file named by :func:`point_key`, the SHA-256 of its inputs (parameters,
variant, tier, tolerances, the point) and of :func:`model_code_hash` (the source of every module a prediction
depends on, and scipy's version), so a change of the model's code invalidates every entry with no version to
bump.  Used by :mod:`dyno.model.overlay`, :mod:`dyno.model.overlay_service` and the studies' task cache.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import asdict
from pathlib import Path

from dyno.model.params import ModelParams, OperatingPoint, bad_input

TIERS = ("closed_form", "full")
# Every module a prediction's numbers depend on: the cache key hashes their source, so a change of the maths
# (a fix, a new boundary condition) invalidates old entries and retries cached failures, with no version to
# bump; the plumbing that carries a job (overlay, overlay_service, overlay_worker, this module) is not hashed,
# so reshaping it keeps the cache (issue 34: a line split in the worker threw away every cell).
MODEL_MODULES = ("params", "geometry", "capstan", "closed_form", "equations", "boundary", "guess", "collocation",
                  "bvp", "balance", "solution", "point_solve")


@functools.lru_cache(maxsize=1)
def model_code_hash() -> str:
    """SHA-256 of the model's source files (and scipy's version, whose solver the full tier runs)."""
    return code_hash(Path(__file__).resolve().parent)


def code_hash(model_dir: Path) -> str:
    """SHA-256 of the :data:`MODEL_MODULES` found in ``model_dir`` and scipy's version."""
    h = hashlib.sha256()
    for name in MODEL_MODULES:
        h.update(name.encode())
        h.update((Path(model_dir) / f"{name}.py").read_bytes())
    try:
        from importlib.metadata import version

        h.update(version("scipy").encode())
    except Exception:  # noqa: BLE001  (no metadata: the source hash alone)
        pass
    return h.hexdigest()


def default_cache_dir() -> Path:
    env = os.environ.get("DYNO_MODEL_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "dyno" / "model"


def point_key(params: ModelParams, op: OperatingPoint, tier: str, variant: str, slip_threshold_m_s: float, tol: float) -> str:
    payload = {
        "code": model_code_hash(),
        "params": params.as_dict(),
        "op": asdict(op),
        "tier": tier,
        "variant": variant,
        "slip": slip_threshold_m_s,
        "tol": tol,
    }
    text = json.dumps(payload, sort_keys=True, default=float)
    return hashlib.sha256(text.encode()).hexdigest()


def as_point(item, slack_tension_n, primary_axial_force_n) -> OperatingPoint:
    if isinstance(item, OperatingPoint):
        return item
    if isinstance(item, dict):
        ratio, rpm, torque = item["ratio"], item["primary_speed_rpm"], item["primary_torque_nm"]
    else:
        try:
            ratio, rpm, torque = item
        except (TypeError, ValueError):
            raise bad_input("points", f"(ratio, primary_speed_rpm, primary_torque_nm) triples, got {item!r}") from None
    return OperatingPoint(
        ratio=float(ratio),
        primary_speed_rpm=float(rpm),
        primary_torque_nm=float(torque),
        slack_tension_n=None if primary_axial_force_n is not None else slack_tension_n,
        primary_axial_force_n=primary_axial_force_n,
    )
