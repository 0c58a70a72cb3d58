"""Predicted efficiency and axial forces for measured operating points, cached on disk.

The app hands over measured points (geometric ratio, primary speed, primary
torque); two tiers answer:

* ``tier="closed_form"``: microseconds per point, for an instant overlay.  Its
  efficiency is Reynolds' creep only (no seating loss): an upper bound.
* ``tier="full"``: the thesis's BVP, 0.3-9 s per point, through
  :class:`dyno.model.overlay_service.OverlayService` run inline: each point
  warm-started from the nearest solved one (in this call, or stored on disk by
  an earlier one) when it is near enough, else cold.

Every result is stored as one small JSON file named by the SHA-256 of its
inputs (parameters, variant, tier, tolerances, the point) and of the model's
source code (:func:`model_code_hash`), so a replay or a UI refresh never
solves the same point twice, and a change of the model's code invalidates
every entry.  Failures are cached too, with their message, and come back with
``converged: false`` rather than a number (retried once the code changes).
Full-tier results carry the balances; ``as_published`` ones a ``warning``.  Cache directory: the
``cache_dir`` argument, else ``$DYNO_MODEL_CACHE``, else
``~/.cache/dyno/model``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from dyno.model.params import ModelParams, TABLE_6_1, bad_input

# the cache's keys live in cache_keys (the overlay service needs them without this module, which runs the service)
from dyno.model.cache_keys import TIERS, as_point, default_cache_dir, point_key
from dyno.model.point_solve import closed_form_result as _closed_form_result  # noqa: E402


def all_cached(points, params: ModelParams = TABLE_6_1, **kwargs) -> bool:
    """Whether :func:`predict_overlay` with the same arguments would answer every point from the cache
    (the keyword arguments of :func:`cached_mask`)."""
    return all(cached_mask(points, params, **kwargs))


def cached_mask(
    points,
    params: ModelParams = TABLE_6_1,
    *,
    tier: str = "full",
    variant: str = "corrected",
    slack_tension_n: float = 100.0,
    primary_axial_force_n: float | None = None,
    slip_threshold_m_s: float = 1e-4,
    tol: float = 1e-3,
    cache_dir: str | os.PathLike | None = None,
) -> list[bool]:
    """Per point: whether the cache already holds its ``tier`` result (no solve needed to show it)."""
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    out = []
    for item in points:
        op = as_point(item, slack_tension_n, primary_axial_force_n)
        out.append((cache / f"{point_key(params, op, tier, variant, slip_threshold_m_s, tol)}.json").is_file())
    return out


def predict_overlay(
    points,
    params: ModelParams = TABLE_6_1,
    *,
    tier: str = "full",
    variant: str = "corrected",
    slack_tension_n: float = 100.0,
    primary_axial_force_n: float | None = None,
    slip_threshold_m_s: float = 1e-4,
    tol: float = 1e-3,
    cache_dir: str | os.PathLike | None = None,
    use_cache: bool = True,
    time_limit_s: float = 60.0,
) -> list[dict]:
    """Predictions for each point, in input order.

    ``points``: iterable of ``(ratio, primary_speed_rpm, primary_torque_nm)``
    triples, dicts with those keys, or :class:`OperatingPoint`.  The tension
    level is ``slack_tension_n`` unless ``primary_axial_force_n`` is given.
    Each result dict has ``ratio``, ``primary_speed_rpm``,
    ``primary_torque_nm``, ``converged``, ``tier``, ``efficiency``
    {speed, torque, overall}, ``axial_force_n`` {primary, secondary},
    ``span_tension_n``, ``cached`` and, for failures, ``error``.
    """
    if tier not in TIERS:
        raise bad_input("tier", f"one of {', '.join(TIERS)}, got {tier!r}")
    ops = [as_point(p, slack_tension_n, primary_axial_force_n) for p in points]
    if tier == "full":
        # The live overlay's service, run inline: cache, nearest-neighbour warm starts (also from solutions
        # stored by earlier sessions), cold fallback.
        from dyno.model.overlay_worker import InlineExecutor
        from dyno.model.overlay_service import OverlayService

        svc = OverlayService(params, executor=InlineExecutor(), variant=variant, slip_threshold_m_s=slip_threshold_m_s,
                             tol=tol, cache_dir=cache_dir, use_cache=use_cache, time_limit_s=time_limit_s)
        keys = [svc.submit(op) for op in ops]
        svc.retry_failures()  # a failed first point, warm from the points of its run solved after it
        return [dict(svc.get(k)) for k in keys]
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    results: list = [None] * len(ops)
    for i, op in enumerate(ops):
        key = point_key(params, op, tier, variant, slip_threshold_m_s, tol)
        path = cache / f"{key}.json"
        if use_cache and path.is_file():
            try:
                results[i] = {**json.loads(path.read_text()), "cached": True}
                continue
            except (OSError, ValueError):
                pass  # unreadable entry: recompute and overwrite
        res = _closed_form_result(params, op)
        res.update(ratio=op.ratio, primary_speed_rpm=op.primary_speed_rpm, primary_torque_nm=op.primary_torque_nm,
                   variant=variant)
        if use_cache:
            try:
                cache.mkdir(parents=True, exist_ok=True)
                tmp = cache / f"{key}.json.tmp"
                tmp.write_text(json.dumps(res, default=float))
                tmp.replace(path)  # atomic: a reader never sees half a file
            except OSError:
                pass  # a read-only cache must not break the overlay
        results[i] = {**res, "cached": False}
    return results


def overlay_fast_then_full(points, params: ModelParams = TABLE_6_1, **kwargs):
    """Generator: the closed-form overlay at once, then the full-model one (for a UI worker)."""
    fast_kwargs = {k: v for k, v in kwargs.items() if k in ("slack_tension_n", "primary_axial_force_n", "cache_dir", "use_cache")}
    yield predict_overlay(points, params, tier="closed_form", **fast_kwargs)
    yield predict_overlay(points, params, tier="full", **kwargs)


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)
