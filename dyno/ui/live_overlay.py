"""The live screen's belt-model overlay: the accepted points submitted to the solver, the curve drawn back.

A mixin of :class:`dyno.ui.live_app.LiveApp` (the ``o`` key and its glue), split from it along the one
seam that runs off the UI thread.  The full model runs in :mod:`dyno.model.overlay_service` (one
background process, warm starts from the nearest solved point, cache); the screen only submits the
accepted points and draws what has come back.  Nothing here may hold the event loop on which the
poller and the controller run: imports, the solver process's start and each point's inverse run in
worker threads.
"""

from __future__ import annotations

import math
import threading
import time

from dyno.model.overlay_inputs import overlay_inputs


class OverlayMixin:
    """The overlay's state and work; the host app provides ``session``, ``values``, ``_draw_plot``, ``_show_fields``,
    ``say``, ``run_worker``, ``call_from_thread`` and ``is_running`` (a Textual App)."""

    def _init_overlay(self) -> None:
        self.overlay: list | None = None  # closed-form efficiency of the points the full model has not solved yet
        self.overlay_full: list = []  # (secondary rpm, full-model efficiency)
        self.overlay_tier = ""
        self.overlay_requested = False
        self.overlay_service = None  # dyno.model.overlay_service.OverlayService, from the first request
        self.overlay_cache_dir = None  # the model cache's default unless set (a test's own directory)
        self._overlay_points = -1
        self._overlay_pairs: list = []  # overlay_inputs of the submitted points, in order
        self._overlay_keys: list = []
        self._overlay_closed: dict = {}
        self._overlay_seen_s: dict = {}
        self._overlay_loop = None  # the event loop, known once the overlay is first requested
        self._overlay_listening = None  # the controller whose accepted points are submitted at once
        self._overlay_lock = threading.Lock()  # submissions come from worker threads
        self._overlay_tune_cache = None  # the rig's Tune, False for none, None before the first look
        self._overlay_primed_s = -math.inf
        self._overlay_shown_s: dict = {}
        self._overlay_logged: set = set()  # keys whose answer is in the run log (an 'overlay' document)
        self._overlay_version = 0

    def action_overlay(self) -> None:
        self.overlay_requested = not self.overlay_requested
        if not self.overlay_requested:
            self.overlay, self.overlay_tier = None, ""
            self.say("overlay off")
        else:
            self.say("belt-model overlay: closed form now, full model per point in the background")
            self._start_overlay()
        self._show_fields()  # on screen at the key, not at the next refresh (1 s while nothing runs)
        self._draw_plot()

    def _start_overlay(self) -> None:
        """Submit the points not yet submitted (the service solves each once), closed form for the rest.

        The work runs in a worker thread: the imports, the solver process's start and the inverse of each
        point (tens of ms) must never hold the event loop on which the poller and the controller run.
        """
        pts = list(self.session.controller.points)
        self._overlay_points = len(pts)
        ctrl = self.session.controller
        if self._overlay_listening is not ctrl:  # (a re-armed session has a new controller)
            import asyncio

            self._overlay_listening = ctrl
            loop = self._overlay_loop = asyncio.get_running_loop()
            # Submit a point as soon as the controller accepts it (not at the next refresh); deferred to the
            # loop so that nothing of the overlay runs inside the controller's own call.
            ctrl.listeners.append(lambda _c: loop.call_soon(self._overlay_on_points))
        accepted_s = time.monotonic()
        self.run_worker(lambda: self._overlay_submit_work(pts, accepted_s), thread=True,
                        group="overlay-submit", name="overlay submit")

    def _overlay_service_now(self):
        """The service, made on first use (in a worker thread, see _start_overlay)."""
        if self.overlay_service is None:
            # The solver runs in its own process (its numerics must not hold this interpreter's GIL, which
            # the poller and the controller need), imported there.
            from dyno.model.overlay_service import OverlayService
            from dyno.model.overlay_worker import process_pool

            loop = self._overlay_loop
            pool, cancel = process_pool()
            self.overlay_service = OverlayService(
                executor=pool, cancel=cancel, cache_dir=self.overlay_cache_dir,
                on_result=lambda key, res: loop.call_soon_threadsafe(self._overlay_changed, key))
            if not self.is_running:  # the app closed while this thread started it: stop it too
                self.overlay_service.close()
        return self.overlay_service

    def _overlay_tune(self):
        """The rig's tune (the run's tune.toml source) for the inverse's clamp; None: Table 6.1 at 100 N."""
        if self._overlay_tune_cache is None:
            path = getattr(self.session.controller, "tune_path", None)
            tune = False
            if path is not None:
                from dyno.tuning.tune import load_tune

                try:
                    tune = load_tune(path)
                except Exception:  # noqa: BLE001  (validated when the run started; never break the overlay)
                    tune = False
            self._overlay_tune_cache = tune
        return self._overlay_tune_cache or None

    def _overlay_submit_work(self, pts, accepted_s: float) -> None:
        with self._overlay_lock:
            svc = self._overlay_service_now()
            pairs = overlay_inputs(pts, self._overlay_tune())
            done = len(self._overlay_pairs)
            new = pairs[done:] if pairs[:done] == self._overlay_pairs else pairs
            if new is pairs:  # not an extension of what was submitted (cannot happen in a run): start over
                self._overlay_pairs, self._overlay_keys = [], []
            for rs, op in new:
                self._overlay_pairs.append((rs, op))
                key = svc.submit(op)
                self._overlay_keys.append(key)
                self._overlay_seen_s.setdefault(key, accepted_s)
            submitted = list(self._overlay_pairs)
        if not pts:
            self.call_from_thread(self._overlay_prime)
        self._closed_form_work(submitted)

    def _overlay_on_points(self) -> None:
        if self.overlay_requested and len(self.session.controller.points) != self._overlay_points:
            self._start_overlay()

    def _overlay_prime(self) -> None:
        """A seed near the coming point while the controller settles/measures, if nothing solved is near it
        (checked at most once a second, the inverse in a worker thread)."""
        svc, v = self.overlay_service, self.values
        if svc is None or v is None or not svc.idle or time.monotonic() - self._overlay_primed_s < 1.0:
            return
        self._overlay_primed_s = time.monotonic()
        live = {"rpm_primary": v.rpm_primary, "ratio": v.ratio, "power_in_w": v.power_engine_w,
                "rpm_secondary": v.rpm_secondary}
        self.run_worker(lambda: self._overlay_prime_work(svc, live), thread=True, group="overlay-prime",
                        name="overlay seed")

    def _overlay_prime_work(self, svc, live: dict) -> None:
        seed = [op for _, op in overlay_inputs([live], self._overlay_tune())]
        if not seed:
            from dyno.model.params import TABLE_6_1_POINT  # nothing measured yet: the thesis's case

            seed = [TABLE_6_1_POINT]
        if svc.nearest_distance(seed[0]) > 0.5:
            svc.prime(seed[0])

    def _closed_form_work(self, pairs) -> None:
        from dyno.model.cache_keys import as_point
        from dyno.model.point_solve import closed_form_result as _closed_form_result
        from dyno.model.params import TABLE_6_1

        out = {}
        for _, op in pairs:
            if op in self._overlay_closed:
                continue
            try:
                out[op] = _closed_form_result(TABLE_6_1, as_point(op, 100.0, None))
            except Exception:  # noqa: BLE001  (a placeholder: a point outside its range has none)
                pass
        self.call_from_thread(self._set_closed_form, out)

    def _set_closed_form(self, out: dict) -> None:
        self._overlay_closed.update(out)
        self._overlay_changed()

    def _overlay_changed(self, key: str | None = None) -> None:
        """Rebuild the curve: the full model where solved, the closed form (marked) where not yet."""
        svc = self.overlay_service
        if svc is None:
            return
        full, rough, failed, newly, refused = [], [], 0, [], []
        for (rs, op), k in zip(self._overlay_pairs, self._overlay_keys):
            r = svc.get(k)
            if r is not None and r.get("converged") and r.get("efficiency"):
                full.append((rs, float(r["efficiency"]["overall"])))
                newly.append(k)
                continue
            if r is not None:
                failed += 1
                refused.append(k)
            cf = self._overlay_closed.get(op)
            if cf is not None:
                rough.append((rs, float(cf["efficiency"]["overall"])))
        self.overlay_full, self.overlay = full, rough
        n = len(self._overlay_pairs)
        self.overlay_tier = (f"full {len(full)}/{n}" + (f", {svc.pending} wait" if svc.pending else "")
                             + (f", {failed} fail" if failed else "")) if n else "no points yet"
        self._overlay_version += 1
        if self.overlay_requested and self.is_running:
            from textual.css.query import NoMatches

            try:
                self._show_fields()  # its status, and a prediction that came back: on screen now, not at
                if key is not None:  # the next refresh
                    self._draw_plot()
            except NoMatches:  # a dialog is on top: the next refresh draws it
                pass
        now = time.monotonic()
        for k in newly:
            if k not in self._overlay_shown_s:
                self._overlay_shown_s[k] = now
                self._overlay_log(k, now, solved=True)
        for k in refused:  # the model's answer was no solution (gross slip, out of range): answered all the same
            if k not in self._overlay_logged:
                self._overlay_log(k, now, solved=False)

    def _overlay_log(self, key: str, shown_s: float, solved: bool) -> None:
        """The run log's record of the full model's answer on screen (a value, or ``solved`` false: none): which
        points, how long after their acceptance (wall seconds; bench/bench_pi_budget.py reads the overlay's lag
        behind the points from these)."""
        self._overlay_logged.add(key)
        writer = getattr(getattr(self.session, "ctx", None), "writer", None)
        if writer is None or key not in self._overlay_seen_s:
            return
        indices = [i for i, k in enumerate(self._overlay_keys) if k == key]
        try:
            writer.doc("overlay", points=indices, solved=solved, lag_s=round(shown_s - self._overlay_seen_s[key], 3))
        except Exception:  # noqa: BLE001  (a record of the display: never an error on the screen's path)
            pass

    def overlay_latencies_s(self) -> dict:
        """Per point: seconds from its acceptance by the controller to its full-model value in the curve."""
        return {k: self._overlay_shown_s[k] - self._overlay_seen_s[k] for k in self._overlay_shown_s
                if k in self._overlay_seen_s}
