"""The kill-chain drills (issue 49): a path that can cut the engine is broken from the start, so the kill-path
probe before GO (:mod:`dyno.control.kill_probe`) must find it and end the test before any load.

=====================  ======================================================================================
drill                  what breaks at T (in the physics: :mod:`dyno.sim.kill_chain`)
=====================  ======================================================================================
kill-lead-open         the magneto's kill lead (or its ground return) is open: K1 grounds nothing, the engine
                       fires whatever the chain does (abort ``kill_path_failed``, ``path`` ``kill_lead``)
kill-relay-welded      the Pi's switch in the chain conducts whatever GPIO24 says (Q1 shorted; an
                       ``energise_to_kill`` rig's own kill relay welded): ``path`` ``pi_relay``
run-enable-shorted     the Nano's run-enable driver conducts whatever D7 says (Q2 or D7's wire shorted):
                       ``path`` ``nano_run_enable``
=====================  ======================================================================================

Posed at ``@0`` they stand before the engine starts.  The verdict is the physics': ``probe_true_dips_rpm``
is how far the true engine speed fell in each probe's window (what the probe should have seen).
"""

from __future__ import annotations

#: name -> (argument required?, allowed arguments or None, needs an engine?) as ``dyno.session.drills.DRILLS``
KILL_DRILLS: dict[str, tuple[bool, tuple | None, bool]] = {
    "kill-lead-open": (False, None, True),
    "kill-relay-welded": (False, None, True),
    "run-enable-shorted": (False, None, True),
}
#: the path each drill breaks, as the abort names it
KILL_DRILL_PATH = {"kill-lead-open": "kill_lead", "kill-relay-welded": "pi_relay",
                   "run-enable-shorted": "nano_run_enable"}
_MODEL_FAULT = {"kill-lead-open": "kill_lead_open", "kill-relay-welded": "pi_switch_welded",
                "run-enable-shorted": "run_enable_shorted"}
#: the probe's kill changes are no safe state: this margin around its window, in sim seconds
PROBE_WINDOW_MARGIN_S = 0.005


def probe_kill_windows(ctx) -> list[tuple[float, float]]:
    """The sim-time spans of the Pi relay probe's cut (its kill and its restore), for
    :func:`dyno.sim.rig.wired_states`: a 100 ms probe is not the run's safe state."""
    probe = getattr(getattr(ctx, "controller", None), "kill_probe", None) or {}
    to_sim = getattr(ctx, "host_to_sim", None) or (lambda t: t)
    m = PROBE_WINDOW_MARGIN_S
    return [(to_sim(p["kill_host_s"]) - m, to_sim(p["restore_host_s"]) + m) for p in probe.get("paths", ())
            if p.get("kill_host_s") is not None and p.get("restore_host_s") is not None]


def probe_true_dips(ctx) -> dict:
    """path -> how far the true primary speed fell in that probe's window (sim truth: the last sample before
    the window less the lowest in it), rpm."""
    from bisect import bisect_left, bisect_right

    truth = ctx.sim.truth
    to_sim = getattr(ctx, "host_to_sim", None) or (lambda t: t)
    out = {}
    for p in (getattr(ctx.controller, "kill_probe", None) or {}).get("paths", ()):
        t0 = p.get("kill_host_s", p.get("request_host_s"))
        t1 = p.get("end_host_s")
        if t0 is None or t1 is None:
            continue
        i, j = bisect_left(truth.t, to_sim(t0)), bisect_right(truth.t, to_sim(t1))
        if 0 < i < j:
            out[p["path"]] = round(truth.rp[i - 1] - min(truth.rp[i:j]), 1)
    return out


class KillDrills:
    """The kill-chain drills' actions: a mixin of :class:`dyno.session.drills.DrillRunner`."""

    def _kill_fault(self, d, rec: dict) -> None:
        setattr(self.ctx.sim.model, _MODEL_FAULT[d.name], True)
        rec["path"] = KILL_DRILL_PATH[d.name]

    _kill_lead_open = _kill_relay_welded = _run_enable_shorted = _kill_fault

    def _kill_verdict(self, rec: dict) -> tuple[bool, str]:
        """(hazard arose, why not): the broken path stood while the engine ran (the physics' truth)."""
        rec["probe_true_dips_rpm"] = probe_true_dips(self.ctx)
        truth = self.ctx.sim.truth
        ran = any(rp > 1000.0 for t, rp in zip(truth.t, truth.rp) if t >= rec["onset_s"])
        return ran, "the engine never ran after the onset: a broken kill path had nothing to cut"
