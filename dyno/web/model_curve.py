"""The belt model beside the live page's points (the terminal UI's `o` overlay, for the page).

Each new valid point is taken to the model's operating point by the slip-consistent inverse (the run's
``tune.toml`` gives the clamp; :func:`dyno.model.overlay_inputs.overlay_inputs`), and the full model (the thesis's
BVP) is solved for it in its own low-priority process (:class:`dyno.model.overlay_service.OverlayService`
with :func:`~dyno.model.overlay_worker.process_pool`, sharing the model cache with the UI and the report):
seconds a point, so the page shows the closed form — creep loss only, an upper bound, marked as such — until
the full model's value arrives.  Runs in the web server's thread, never on the rig's loop.
"""

from __future__ import annotations

import os
from pathlib import Path


def _default_service():
    from dyno.model.overlay_service import OverlayService
    from dyno.model.overlay_worker import process_pool

    pool, cancel = process_pool()
    for pid in list(getattr(pool, "_processes", {}) or {}):  # the solver yields the cores to the rig's process
        try:
            os.setpriority(os.PRIO_PROCESS, pid, 19)
        except (OSError, AttributeError):
            pass
    return OverlayService(executor=pool, cancel=cancel)


class ModelCurve:
    """Points in, the ``model`` part of each frame out (see the module docstring)."""

    def __init__(self, service_factory=_default_service) -> None:
        self._factory = service_factory
        self._svc = None
        self._run_dir = None
        self._rows_seen = 0
        self._items: list[dict] = []
        self._no_steady = 0
        self.closed = False

    def update(self, snap: dict) -> dict:
        """Submit the frame's new points (a re-armed session's new run starts afresh); the model's part."""
        run_dir = snap.get("run_dir")
        rows = snap.get("points") or []
        if run_dir != self._run_dir or len(rows) < self._rows_seen:
            self._run_dir, self._rows_seen, self._items, self._no_steady = run_dir, 0, [], 0
        new = [r for r in rows[self._rows_seen:] if r.get("valid") is not False and r.get("efficiency") is not None]
        self._rows_seen = len(rows)
        if new and not self.closed:
            self._submit(new)
        return self.frame()

    def _submit(self, rows: list[dict]) -> None:
        from dyno.model.overlay import predict_overlay
        from dyno.model.overlay_inputs import overlay_inputs

        tune = Path(self._run_dir) / "tune.toml" if self._run_dir else None
        tune = tune if tune is not None and tune.is_file() else None
        for r in rows:
            try:
                pairs = overlay_inputs([r], tune)
            except Exception:  # noqa: BLE001 - a page's curve must never break the page
                pairs = []
            if not pairs:  # no steady belt at the tune's clamp (gross slip, the spring holding it open)
                self._no_steady += 1
                continue
            op = pairs[0][1]
            (cf,) = predict_overlay([op], tier="closed_form")
            if self._svc is None:
                self._svc = self._factory()
            self._items.append({"index": r.get("index"), "ratio": r.get("ratio"), "key": self._svc.submit(op),
                                "closed_form": float(cf["efficiency"]["overall"]) if cf.get("converged") else None})

    def frame(self) -> dict:
        pts, n_full = [], 0
        for it in self._items:
            res = self._svc.get(it["key"]) if self._svc is not None else None
            if res is not None and res.get("converged") and res.get("efficiency"):
                pts.append({"index": it["index"], "ratio": it["ratio"], "tier": "full",
                            "efficiency": float(res["efficiency"]["overall"])})
                n_full += 1
            elif it["closed_form"] is not None:
                pts.append({"index": it["index"], "ratio": it["ratio"], "tier": "closed_form",
                            "efficiency": it["closed_form"]})
        return {"points": pts, "full": n_full, "of": len(self._items), "no_steady_belt": self._no_steady,
                "pending": self._svc.pending if self._svc is not None else 0,
                "label": "belt model: full (thesis BVP, Table 6.1 belt) where solved; closed form (creep loss "
                         "only: an upper bound) until then"}

    @property
    def version(self) -> tuple:
        """Changes when a full-model value arrives (the page is sent the frame again)."""
        if self._svc is None:
            return (len(self._items), 0)
        return (len(self._items), sum(self._svc.get(it["key"]) is not None for it in self._items))

    def close(self) -> None:
        self.closed = True
        if self._svc is not None:
            self._svc.close()
