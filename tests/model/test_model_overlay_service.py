"""The background overlay service: incremental, warm-started, cached; no Textual.

Warm vs cold is asserted on continuation steps (= solve_bvp calls), never on wall time.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from dyno.model import cache_keys, overlay
from dyno.model.overlay_worker import Cancelled, InlineExecutor, solve_job
from dyno.model.overlay_service import OverlayService, op_distance
from dyno.model.point_solve import WarmState
from dyno.model.params import TABLE_6_1, OperatingPoint

SLIP = 1e-3  # a looser friction law than the default 1e-4: the same code paths, ~2x quicker solves
# Consecutive points of a simulated run (ratio +5 %, the engine a little faster, the torque a little lower).
RUN = [(1.0, 3400.0, 18.0), (1.05, 3430.0, 17.6), (1.10, 3460.0, 17.2)]


def service(tmp_path, **kw) -> OverlayService:
    kw.setdefault("executor", InlineExecutor())
    return OverlayService(TABLE_6_1, slip_threshold_m_s=SLIP, cache_dir=tmp_path, time_limit_s=60, **kw)


def close(a: dict, b: dict) -> None:
    for k in ("speed", "torque", "overall"):
        assert a["efficiency"][k] == pytest.approx(b["efficiency"][k], abs=2e-5), k
    for k in ("primary", "secondary"):
        assert a["axial_force_n"][k] == pytest.approx(b["axial_force_n"][k], rel=2e-4), k


def test_incremental_warm_started_equal_to_cold_and_cached(tmp_path):
    seen = []
    svc = service(tmp_path / "c", on_result=lambda key, res: seen.append(key))
    k0 = svc.submit(RUN[0])
    r0 = svc.get(k0)
    assert r0["converged"] and r0["start"] == "cold" and r0["steps"] > 1 and svc.solves == 1
    k1 = svc.submit(RUN[1])
    r1 = svc.get(k1)
    assert r1["converged"] and r1["start"] == "warm" and r1["warm_from"]["ratio"] == 1.0
    # the same point solved cold, without any neighbour: the same answer, in more continuation steps
    cold = service(tmp_path / "cold", use_cache=False, warm_max_distance=0.0)
    rc = cold.get(cold.submit(RUN[1]))
    assert rc["start"] == "cold"
    close(r1, rc)
    assert r1["steps"] < rc["steps"], (r1["steps"], rc["steps"])
    # incremental: the whole list again plus one new point is one more solve, not three
    keys = [svc.submit(p) for p in RUN]
    assert keys[:2] == [k0, k1] and svc.solves == 3 and svc.get(keys[2])["start"] == "warm"
    assert seen == keys  # every displayed point reported once
    # another session: answered from the disk cache (no solve), and a new point warm-starts from the
    # solutions the first session stored
    again = service(tmp_path / "c")
    assert all(again.get(again.submit(p))["cached"] for p in RUN) and again.solves == 0
    new = again.get(again.submit((1.15, 3490.0, 16.8)))
    # one homotopy step (to the continuation's tolerance), then that solution refined to tol: two attempts
    assert new["start"] == "warm" and new["steps"] == 2 and again.solves == 1
    # predict_overlay (the report's path) is the same service, inline
    res = overlay.predict_overlay(RUN, slip_threshold_m_s=SLIP, cache_dir=tmp_path / "c")
    assert [r["cached"] for r in res] == [True, True, True]
    close(res[1], r1)


def test_far_neighbour_is_not_used_and_failed_warm_start_falls_back_to_cold():
    near = op_distance(OperatingPoint(1.0, 3400.0, 18.0), OperatingPoint(1.05, 3430.0, 17.6))
    far = op_distance(OperatingPoint(1.0, 3400.0, 18.0), OperatingPoint(0.73, 3710.0, 8.5))
    assert near < 1.0 < far  # ratio 1.0 -> 0.73 warm took 8.8 s against 2.6 s cold: not a neighbour
    calls = []

    def flaky(params, op, guess=None, **kw):
        from dyno.errors import DidNotConverge

        calls.append(guess is not None)
        if guess is not None:
            raise DidNotConverge("stalled")
        return _fake_result(op)

    from dyno.model import solution

    orig = solution.solve_point
    try:
        solution.solve_point = flaky
        ws = WarmState(None, np.zeros(2), np.zeros((2, 2)), np.zeros(1), None, OperatingPoint(), "corrected", SLIP)
        res, warm = solve_job(TABLE_6_1, OperatingPoint(), variant="corrected", slip_threshold_m_s=SLIP, tol=1e-3,
                              time_limit_s=5, guess=ws)
    finally:
        solution.solve_point = orig
    assert calls == [True, False] and res["start"] == "cold after a failed warm start" and res["converged"]


def _fake_result(op):
    from types import SimpleNamespace

    raw = SimpleNamespace(case=None, t=np.zeros(3), y=np.zeros((2, 3)), p=np.zeros(2), rms_residuals=None,
                          history=[1])
    summary = {"efficiency": {"speed": 1.0, "torque": 0.9, "overall": 0.9}, "axial_force_n": {"primary": 1.0,
               "secondary": 1.0}, "span_tension_n": {"tight": 2.0, "slack": 1.0}, "residual_max": 0.0,
               "slip_threshold_m_s": SLIP, "solve_s": 0.0, "balance": {}}
    return SimpleNamespace(raw=raw, summary=summary)


def fake_solver(log: list, fail: bool = False, gate: threading.Event | None = None):
    """A stand-in for solve_job: records (ratio, warm-from ratio) and returns a warm state at the point."""

    def solve(params, op, *, variant, slip_threshold_m_s, tol, time_limit_s, guess=None, cancel=None,
              fallback=None):
        if gate is not None:
            gate.wait(5)
        log.append((op.ratio, None if guess is None else guess.op.ratio))
        if fail:
            return ({"converged": False, "tier": "full", "state": "failed", "error": "stalled", "ratio": op.ratio,
                     "primary_speed_rpm": op.primary_speed_rpm, "primary_torque_nm": op.primary_torque_nm}, None)
        res = {"converged": True, "tier": "full", "efficiency": {"overall": 0.9}, "ratio": op.ratio,
               "primary_speed_rpm": op.primary_speed_rpm, "primary_torque_nm": op.primary_torque_nm,
               "start": "cold" if guess is None else "warm", "steps": 1}
        return res, WarmState(None, np.zeros(2), np.zeros((2, 2)), np.zeros(1), None, op, variant,
                              slip_threshold_m_s)

    return solve


def test_background_thread_solves_in_arrival_order_each_from_its_nearest_solved_point(tmp_path):
    log, results = [], {}
    gate = threading.Event()
    with ThreadPoolExecutor(1) as pool:
        svc = service(tmp_path, executor=pool, solve=fake_solver(log, gate=gate), use_cache=False,
                      on_result=lambda k, r: results.__setitem__(k, r))
        first = svc.submit((1.0, 3400.0, 18.0))  # running (held at the gate) while the batch arrives
        batch = [svc.submit((r, 3400.0, 18.0)) for r in (1.05, 1.6, 1.1, 1.55)]
        assert svc.pending == 5
        gate.set()
        assert svc.wait_idle(10)
    assert set(results) == {first, *batch} and svc.pending == 0
    # arrival order; each warm from the nearest solved point; 1.6 is too far from 1.05 (+42 %): cold
    assert log == [(1.0, None), (1.05, 1.0), (1.6, None), (1.1, 1.05), (1.55, 1.6)]


def test_prime_is_solved_only_when_nothing_else_waits_and_seeds_the_next_point(tmp_path):
    log = []
    gate = threading.Event()
    with ThreadPoolExecutor(1) as pool:
        svc = service(tmp_path, executor=pool, solve=fake_solver(log, gate=gate), use_cache=False)
        svc.submit((2.0, 3400.0, 18.0))
        svc.prime((1.0, 3400.0, 18.0))
        svc.submit((2.2, 3400.0, 18.0))
        assert svc.pending == 2  # the seed is not a displayed point
        gate.set()
        assert svc.wait_idle(10)
        assert [r for r, _ in log] == [2.0, 2.2, 1.0]
        svc.submit((1.02, 3400.0, 18.0))
        assert svc.wait_idle(10)
    assert log[-1] == (1.02, 1.0)


def test_failed_entry_is_cached_and_retried_when_the_model_code_changes(tmp_path, monkeypatch):
    log = []
    svc = service(tmp_path, solve=fake_solver(log, fail=True))
    r = svc.get(svc.submit(RUN[0]))
    assert not r["converged"] and r["state"] == "failed" and len(log) == 1
    again = service(tmp_path, solve=fake_solver(log, fail=True))
    r2 = again.get(again.submit(RUN[0]))
    assert r2["cached"] and not r2["converged"] and len(log) == 1  # same code: the failure is remembered
    from dyno.model import cache_keys

    monkeypatch.setattr(cache_keys, "model_code_hash", lambda: "f" * 64)  # the model's code changed
    changed = service(tmp_path, solve=fake_solver(log))
    r3 = changed.get(changed.submit(RUN[0]))
    assert r3["converged"] and not r3["cached"] and len(log) == 2


def test_close_stops_a_running_solve_at_its_next_continuation_step():
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(Cancelled):
        solve_job(TABLE_6_1, OperatingPoint(), variant="corrected", slip_threshold_m_s=SLIP, tol=1e-3,
                  time_limit_s=60, cancel=cancel)
    with ThreadPoolExecutor(1) as pool:
        svc = OverlayService(TABLE_6_1, executor=pool, use_cache=False, slip_threshold_m_s=SLIP)
        key = svc.submit(RUN[0])
        svc.close()
    assert svc.get(key) is None  # cancelled: nothing shown, nothing cached


def test_stored_warm_states_are_bounded(tmp_path, monkeypatch):
    from dyno.model import overlay_service

    warm = tmp_path / "warm"
    warm.mkdir()
    (warm / "0123456789abcdef-old.npz").write_bytes(b"other model code")
    code = cache_keys.model_code_hash()[:16]
    for i in range(5):
        (warm / f"{code}-{i}.npz").write_bytes(b"damaged")  # unreadable: skipped, not fatal
    monkeypatch.setattr(overlay_service, "KEEP_WARM_FILES", 3)
    svc = service(tmp_path)
    assert svc._warm == [] and not (warm / "0123456789abcdef-old.npz").exists()
    assert len(list(warm.glob("*.npz"))) == 3


def test_process_pool_solves_in_another_interpreter_and_close_cancels(tmp_path):
    """The UI's executor: one spawned process, cancelled through the event it got at start."""
    from dyno.model.overlay_worker import process_pool

    pool, cancel = process_pool()
    svc = OverlayService(TABLE_6_1, executor=pool, cancel=cancel, slip_threshold_m_s=1e-2, cache_dir=tmp_path)
    key = svc.submit(RUN[0])
    assert svc.wait_idle(120)
    r = svc.get(key)
    assert r["converged"] and r["start"] == "cold" and not r["cached"]
    k2 = svc.submit(RUN[1])
    assert svc.wait_idle(60) and svc.get(k2)["start"] == "warm"  # the warm state travelled back and forth
    svc.submit((2.0, 3400.0, 10.0))  # a cold solve of several steps ...
    svc.close()  # ... stopped at its next step
    assert cancel.is_set()
    pool.shutdown(wait=True)


def test_a_dead_worker_process_is_replaced_by_a_thread(tmp_path):
    from concurrent.futures import BrokenExecutor

    class Broken:
        def submit(self, *a, **k):
            raise BrokenExecutor("worker killed")

        def shutdown(self, **k):
            pass

    log = []
    svc = service(tmp_path, executor=Broken(), solve=fake_solver(log), use_cache=False)
    key = svc.submit(RUN[0])
    assert svc.wait_idle(10) and svc.get(key)["converged"] and svc.fallbacks == 1 and len(log) == 1


# --- a failed point retried from its run's neighbours (issue 25 item 4) ---------------------------------


def _retry_service(tmp_path):
    from dyno.model.overlay_worker import InlineExecutor
    from dyno.model.overlay_service import OverlayService

    calls = []

    def solve(params, op, *, variant, slip_threshold_m_s, tol, time_limit_s, guess=None, cancel=None,
              fallback=None):
        """A stand-in solver: the 'heavy' point fails from nothing and converges from any neighbour; the
        'slip' point is gross slip whatever the start."""
        calls.append((op.primary_torque_nm, guess is not None))
        base = {"tier": "full", "ratio": op.ratio, "primary_speed_rpm": op.primary_speed_rpm,
                "primary_torque_nm": op.primary_torque_nm, "variant": variant, "steps": 1, "job_s": 0.0}
        if op.primary_torque_nm == 30.0:
            return {**base, "converged": False, "state": "gross_slip", "error": "gross slip", "start": "cold"}, None
        if op.primary_torque_nm == 10.0 and guess is None:
            return {**base, "converged": False, "state": "failed", "error": "singular", "start": "cold"}, None
        warm = WarmState(case=None, t=np.zeros(2), y=np.zeros((2, 2)), p=np.zeros(1), rms=None, op=op,
                         variant=variant, slip_threshold_m_s=slip_threshold_m_s)
        return {**base, "converged": True, "state": "steady", "efficiency": {"overall": 0.9},
                "start": "warm" if guess is not None else "cold"}, warm

    svc = OverlayService(executor=InlineExecutor(), cache_dir=tmp_path, use_cache=False, solve=solve)
    return svc, calls


def test_a_point_that_failed_cold_is_retried_warm_from_its_runs_next_point(tmp_path):
    from dyno.model.params import OperatingPoint

    svc, calls = _retry_service(tmp_path)
    first = svc.submit(OperatingPoint(ratio=0.72, primary_speed_rpm=3670, primary_torque_nm=10.0))
    assert svc.get(first)["converged"] is False  # solved first, from nothing: failed
    second = svc.submit(OperatingPoint(ratio=0.72, primary_speed_rpm=3550, primary_torque_nm=14.5))
    slip = svc.submit(OperatingPoint(ratio=2.0, primary_speed_rpm=3000, primary_torque_nm=30.0))
    assert svc.get(second)["converged"] is True
    assert svc.retry_failures() == 1  # the numerical failure only: gross slip is the physics' answer
    assert svc.get(first)["converged"] is True and svc.get(first)["start"] == "warm"
    assert svc.get(slip)["state"] == "gross_slip"
    assert svc.retry_failures() == 0  # once each
    assert calls.count((30.0, False)) + calls.count((30.0, True)) == 1


def test_no_retry_without_a_solved_point_to_start_from(tmp_path):
    from dyno.model.params import OperatingPoint

    svc, calls = _retry_service(tmp_path)
    k = svc.submit(OperatingPoint(ratio=0.72, primary_speed_rpm=3670, primary_torque_nm=10.0))
    assert svc.retry_failures() == 0 and svc.get(k)["converged"] is False and len(calls) == 1


def _with_solve_point(fake, **job):
    from dyno.model import solution

    orig = solution.solve_point
    try:
        solution.solve_point = fake
        return solve_job(TABLE_6_1, OperatingPoint(), variant="corrected", slip_threshold_m_s=SLIP, tol=1e-3,
                         time_limit_s=5, **job)
    finally:
        solution.solve_point = orig


def test_a_failed_cold_start_starts_again_from_the_far_neighbour_unless_the_belt_slips():
    from dyno.errors import DidNotConverge, GrossSlip

    far = WarmState(None, np.zeros(2), np.zeros((2, 2)), np.zeros(1), None, OperatingPoint(), "corrected", SLIP)
    for cold_error, expected in ((DidNotConverge("stalled at v_th = 1 m/s"), [None, far]),
                                 (GrossSlip("gross slip"), [None])):
        calls = []

        def cold_fails(params, op, guess=None, **kw):
            calls.append(guess)
            if guess is None:
                raise cold_error
            return _fake_result(op)

        res, _ = _with_solve_point(cold_fails, fallback=far)
        assert calls == expected
        if len(expected) == 2:
            assert res["converged"] and res["start"] == "warm from a far neighbour after a failed cold start"
        else:  # the physics' verdict stands: no second try
            assert not res["converged"] and res["state"] == "gross_slip"


def test_the_service_hands_a_far_neighbour_over_as_the_fallback_only(tmp_path):
    seen = []

    def solve(params, op, *, variant, slip_threshold_m_s, tol, time_limit_s, guess=None, cancel=None,
              fallback=None):
        seen.append((op.ratio, None if guess is None else guess.op.ratio,
                     None if fallback is None else fallback.op.ratio))
        res = {"converged": True, "tier": "full", "efficiency": {"overall": 0.9}, "ratio": op.ratio,
               "primary_speed_rpm": op.primary_speed_rpm, "primary_torque_nm": op.primary_torque_nm,
               "start": "cold" if guess is None else "warm", "steps": 1}
        return res, WarmState(None, np.zeros(2), np.zeros((2, 2)), np.zeros(1), None, op, variant,
                              slip_threshold_m_s)

    svc = service(tmp_path, solve=solve, use_cache=False)
    svc.submit((1.0, 3400.0, 18.0))
    svc.submit((1.05, 3430.0, 17.6))  # a neighbour: warm from it, no fallback
    svc.submit((0.72, 3700.0, 9.0))  # far from both: cold first, the nearer (ratio 1.0) as the fallback
    assert seen == [(1.0, None, None), (1.05, 1.0, None), (0.72, None, 1.0)]


def test_a_heavy_point_the_cold_path_stalls_on_converges_from_the_thesis_point(tmp_path):
    """Real numerics: ratio 0.72 at 17.5 N*m and 856 N of clamp (a full-load point of a simulated run) stalls
    on the cold path's smoothed friction law at the capstan bound; from Table 6.1's solution it converges."""
    svc = OverlayService(TABLE_6_1, cache_dir=tmp_path, use_cache=False, time_limit_s=60)
    seed = svc.get(svc.submit((1.0, 3400.0, 18.0)))
    assert seed["converged"]
    heavy = OperatingPoint(ratio=0.72, primary_speed_rpm=3106.4, primary_torque_nm=17.51, slack_tension_n=None,
                           primary_axial_force_n=856.5)
    assert svc.nearest_distance(heavy) > svc.warm_max_distance  # too far for a first try
    res = svc.get(svc.submit(heavy))
    assert res["converged"], res.get("error")
    assert res["start"] == "warm from a far neighbour after a failed cold start"
    assert res["warm_from"]["ratio"] == 1.0
    assert 0.5 < res["efficiency"]["overall"] < 1.0
    assert res["axial_force_n"]["primary"] == pytest.approx(856.5, rel=1e-3)  # the clamp asked for
