"""Background belt-model overlay: incremental, warm-started, cached (no Textual, no event loop).

A live run accepts a point every ~10-30 s; a cold full-model solve costs 2-9 s
but a solve warm-started from a nearby solution ~0.3-1 s (one continuation
step).  :class:`OverlayService` therefore

* solves only what is new: each operating point is keyed like the disk cache
  (:func:`dyno.model.cache_keys.point_key`: inputs + the model's code hash), a
  point already solved (in memory or on disk, converged or failed) is answered
  at once, and a failed entry is retried only when the model's code changes;
* solves one point at a time on an injected executor (anything with
  ``submit(fn, *args, **kwargs) -> Future``: a one-process pool in the UI
  (:func:`process_pool`), a thread pool, :class:`InlineExecutor` for a batch),
  so every solve can start from all the solutions before it;
* warm-starts each solve from the nearest solved point (:func:`op_distance`),
  when it is near enough (a far neighbour is a worse start than none), else
  solves cold;
  a failed warm start is retried cold, a failed cold start warm from the
  nearest solution however far (:func:`solve_job`'s ``fallback``);
* keeps the solutions it warm-starts from on disk too (``warm/`` under the cache
  directory, one small ``.npz`` per converged point, same code hash), so the
  first point of the next session warm-starts as well;
* solves the accepted points in arrival order (a run's points come as a chain
  of neighbours; a far point must not wait behind nearer successors), seeds last;
* can be *primed* with a point to solve while nothing else waits (a seed near
  where the next points will be), and is cancelled between continuation steps
  by :meth:`OverlayService.close`.

Results have the format of :func:`dyno.model.overlay.predict_overlay` plus
``start`` (``"warm"``, ``"cold"``, ``"cold after a failed warm start"``, ``"warm from a far
neighbour after a failed cold start"``),
``steps`` (continuation steps, i.e. ``solve_bvp`` calls) and ``job_s``.
"""

from __future__ import annotations

import json
import math
import threading
import time
from concurrent.futures import Future
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from dyno.model import cache_keys as _keys
from dyno.model.cache_keys import as_point, default_cache_dir, point_key
from dyno.model.overlay_worker import Cancelled, InlineExecutor, solve_job
from dyno.model.point_solve import WarmState
from dyno.model.params import TABLE_6_1, ModelParams, OperatingPoint

#: Scales of :func:`op_distance` (per unit of log): a warm start is tried up to distance 1.  Measured on a
#: simulated run's points: consecutive points (ratio +5..9 %, rpm +-20 %) warm-start in one continuation step.
RATIO_SCALE, SPEED_SCALE, TORQUE_SCALE, LEVEL_SCALE, SLIP_SCALE = 0.15, 0.5, 0.5, 0.5, 2.0
WARM_MAX_DISTANCE = 1.0
MAX_WARM_FILES = 300  # newest persisted warm states read at start (each ~50-150 kB)
KEEP_WARM_FILES = 1000  # at most this many kept on disk


def _level(op: OperatingPoint) -> tuple[str, float]:
    if op.primary_axial_force_n is not None:
        return "axial", float(op.primary_axial_force_n)
    return "slack", float(op.slack_tension_n if op.slack_tension_n is not None else 100.0)


def op_distance(a: OperatingPoint, b: OperatingPoint, slip_a: float = 1e-4, slip_b: float = 1e-4) -> float:
    """How far apart two operating points are for a warm start (log differences over their scales)."""
    (kind_a, la), (kind_b, lb) = _level(a), _level(b)
    d = [math.log(a.ratio / b.ratio) / RATIO_SCALE,
         math.log(a.primary_speed_rpm / b.primary_speed_rpm) / SPEED_SCALE,
         math.log(max(a.primary_torque_nm, 1e-3) / max(b.primary_torque_nm, 1e-3)) / TORQUE_SCALE,
         math.log(slip_a / slip_b) / SLIP_SCALE]
    if kind_a == kind_b:
        d.append(math.log(la / lb) / LEVEL_SCALE)
    else:
        d.append(0.5)  # switching the tension-level condition costs one homotopy step
    return math.sqrt(sum(x * x for x in d))


@dataclass
class Entry:
    key: str
    op: OperatingPoint
    submitted_s: float
    result: dict | None = None
    done_s: float | None = None
    prime: bool = False
    warm_from: str | None = None  # key of the neighbour it was warm-started from
    extra: dict = field(default_factory=dict)

    @property
    def latency_s(self) -> float | None:
        return None if self.done_s is None else self.done_s - self.submitted_s


class OverlayService:
    """Full-model predictions for points as they come (see the module docstring)."""

    def __init__(self, params: ModelParams = TABLE_6_1, *, executor=None, variant: str = "corrected",
                 slip_threshold_m_s: float = 1e-4, tol: float = 1e-3, slack_tension_n: float = 100.0,
                 primary_axial_force_n: float | None = None, cache_dir=None, use_cache: bool = True,
                 time_limit_s: float = 45.0, on_result=None, clock=time.monotonic, solve=solve_job,
                 warm_max_distance: float = WARM_MAX_DISTANCE, cancel=None) -> None:
        """``cancel``: the event a process pool's workers got at start (:func:`process_pool`); without it the
        service makes a threading.Event and hands it to each job (thread or inline executors).
        ``time_limit_s``: CPU seconds per solve attempt; a cold start at a heavy clamp and a light torque
        takes 16-26 s (2,000 N at 3-10 N*m, ratios 0.72-2.4), so 45 s lets it finish."""
        self.params, self.variant = params, variant
        self.slip_threshold_m_s, self.tol, self.time_limit_s = slip_threshold_m_s, tol, time_limit_s
        self.slack_tension_n, self.primary_axial_force_n = slack_tension_n, primary_axial_force_n
        self.cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        self.use_cache = use_cache
        self.executor = executor if executor is not None else InlineExecutor()
        self.on_result, self.clock, self._solve = on_result, clock, solve
        self.warm_max_distance = warm_max_distance
        self.entries: dict[str, Entry] = {}
        self._pending: list[str] = []  # in arrival order
        self._warm: list[tuple[str, WarmState]] = []
        self._busy: str | None = None
        self._closed = False
        self._pass_cancel = cancel is None
        self._cancel = threading.Event() if cancel is None else cancel
        self._lock = threading.RLock()
        self._idle = threading.Condition(self._lock)
        self.solves = 0  # full-model jobs run (cache hits excluded)
        self.fallbacks = 0  # times a dead worker process was replaced by a thread
        self._code = _keys.model_code_hash()  # via the module: a test may stand in for it
        if use_cache:
            self._load_warm_states()

    # --- public -------------------------------------------------------------------------------------
    def key(self, item) -> str:
        op = as_point(item, self.slack_tension_n, self.primary_axial_force_n)
        return point_key(self.params, op, "full", self.variant, self.slip_threshold_m_s, self.tol)

    def submit(self, item, *, prime: bool = False) -> str:
        """Queue a point (a triple, dict or OperatingPoint); returns its key.  Known points are not solved again."""
        op = as_point(item, self.slack_tension_n, self.primary_axial_force_n)
        key = point_key(self.params, op, "full", self.variant, self.slip_threshold_m_s, self.tol)
        with self._lock:
            if key in self.entries:
                e = self.entries[key]
                if e.prime and not prime:  # a seed that became a real point: its latency counts from now
                    e.prime = False
                    e.submitted_s = self.clock() if e.result is None else e.submitted_s
                return key
            e = Entry(key, op, self.clock(), prime=prime)
            self.entries[key] = e
            # A seed is solved even if its summary is cached: what it is for is the solution to warm-start from.
            cached = None if prime else self._read_cache(key)
            if cached is not None:
                e.result, e.done_s = cached, e.submitted_s
            else:
                self._pending.append(key)
        if e.result is not None:
            self._notify(e)
        else:
            self._pump()
        return key

    def prime(self, item) -> str:
        """Solve ``item`` when nothing else waits (a seed for the warm starts of the points to come)."""
        return self.submit(item, prime=True)

    def retry_failures(self) -> int:
        """Queue once more every point that did not converge, now warm from the nearest point solved in this
        session (however far), when that is not where its failed attempt started; returns how many.

        Points are solved in arrival order, so a run's first point starts from nothing or from a stored
        solution of another run, and at a heavy clamp that can fail where a start from the next point of
        its own run converges. Gross slip is the physics' answer: never retried; each point is retried once.
        """
        n = 0
        with self._lock:
            for key, e in self.entries.items():
                r = e.result
                if (r is None or r.get("converged") or r.get("state") == "gross_slip" or e.prime
                        or e.extra.get("retried") or key in self._pending or key == self._busy):
                    continue
                _, near_key, ws = self._nearest(e.op, session_only=True)
                if ws is None or near_key == e.warm_from:
                    continue  # nothing new to start from
                e.result, e.done_s = None, None
                e.extra["retried"] = True
                self._pending.append(key)
                n += 1
        if n:
            self._pump()
        return n

    def nearest_distance(self, item) -> float:
        """:func:`op_distance` from ``item`` to the nearest solution a warm start could use (inf: none)."""
        op = as_point(item, self.slack_tension_n, self.primary_axial_force_n)
        with self._lock:
            return self._nearest(op)[0]

    def get(self, key: str) -> dict | None:
        with self._lock:
            e = self.entries.get(key)
            return None if e is None else e.result

    @property
    def pending(self) -> int:
        with self._lock:
            return len([k for k in self._pending if not self.entries[k].prime]) + (
                1 if self._busy and not self.entries[self._busy].prime else 0)

    @property
    def idle(self) -> bool:
        """Nothing queued or running (seeds included)."""
        with self._lock:
            return not self._pending and self._busy is None

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until nothing is pending or running (tests, batches, benchmarks)."""
        with self._idle:
            return self._idle.wait_for(lambda: not self._pending and self._busy is None, timeout_s)

    def close(self) -> None:
        """Stop: drop what waits, cancel the running solve at its next continuation step."""
        with self._lock:
            self._closed = True
            self._pending.clear()
            self._cancel.set()
        try:
            self.executor.shutdown(wait=False, cancel_futures=True)
        except TypeError:  # an executor without cancel_futures
            self.executor.shutdown(wait=False)

    # --- scheduling ---------------------------------------------------------------------------------
    def _nearest(self, op: OperatingPoint, session_only: bool = False) -> tuple[float, str | None, WarmState | None]:
        best = (math.inf, None, None)
        for key, ws in self._warm:
            if ws.variant != self.variant or (session_only and key not in self.entries):
                continue
            d = op_distance(op, ws.op, self.slip_threshold_m_s, ws.slip_threshold_m_s)
            if d < best[0]:
                best = (d, key, ws)
        return best

    def _pump(self) -> None:
        with self._lock:
            if self._busy is not None or not self._pending or self._closed:
                if self._busy is None and not self._pending:
                    self._idle.notify_all()
                return
            # Accepted points in arrival order (each must be on screen soon after it came: a point far from
            # everything solved must not wait behind its nearer successors; a run's points arrive as a chain
            # of neighbours anyway), then the newest seed.
            real = [k for k in self._pending if not self.entries[k].prime]
            key = real[0] if real else self._pending[-1]
            self._pending.remove(key)
            self._busy = key
            e = self.entries[key]
            # a retry starts from this session's solutions first (its run's neighbours), then from stored ones
            d, near_key, ws = self._nearest(e.op, session_only=bool(e.extra.get("retried")))
            if ws is None:
                d, near_key, ws = self._nearest(e.op)
            # a retry takes its nearest neighbour of this session however far: its first attempt failed
            guess = ws if d <= self.warm_max_distance or (e.extra.get("retried") and ws is not None) else None
            # too far for a first try, but the start if the cold one fails (see solve_job); not for a seed,
            # an investment that must not hold the accepted points behind it for a second long solve
            fallback = ws if guess is None and not e.prime else None
            e.warm_from = near_key if ws is not None else None
            e.extra["neighbour_distance"] = d
            if ws is not None:
                e.extra["warm_from_op"] = asdict(ws.op)
            self.solves += 1
        try:
            fut = self._submit_job(e, guess, fallback)
        except RuntimeError:  # the executor was shut down under us
            with self._lock:
                self._busy = None
                self._idle.notify_all()
            return
        fut.add_done_callback(lambda f, key=key: self._done(key, f))

    def _submit_job(self, e: Entry, guess, fallback=None):
        from concurrent.futures import BrokenExecutor

        def submit():
            return self.executor.submit(self._solve, self.params, e.op, variant=self.variant,
                                        slip_threshold_m_s=self.slip_threshold_m_s, tol=self.tol,
                                        time_limit_s=self.time_limit_s, guess=guess, fallback=fallback,
                                        **({"cancel": self._cancel} if self._pass_cancel else {}))

        try:
            return submit()
        except BrokenExecutor:
            self._fall_back_to_a_thread()
            return submit()

    def _fall_back_to_a_thread(self) -> None:
        """The worker process died (killed, out of memory): go on in a thread rather than show nothing."""
        from concurrent.futures import ThreadPoolExecutor

        with self._lock:
            self.executor = ThreadPoolExecutor(1, thread_name_prefix="overlay")
            self._pass_cancel = True  # a multiprocessing Event works within this process too
            self.fallbacks += 1

    def _done(self, key: str, fut: Future) -> None:
        from concurrent.futures import BrokenExecutor

        e = self.entries[key]
        try:
            res, warm = fut.result()
        except BrokenExecutor:  # the worker process died under this job: solve it again, in a thread
            self._fall_back_to_a_thread()
            with self._lock:
                self._busy = None
                if not self._closed and self.fallbacks <= 1:
                    self._pending.insert(0, key)
                    self.solves -= 1
            self._pump()
            return
        except (Cancelled, Exception) as exc:  # noqa: BLE001  (cancelled or a bug: not cached, retried next session)
            with self._lock:
                self._busy = None
                if not self._closed:
                    e.result = {"converged": False, "tier": "full", "state": "failed", "cached": False,
                                "error": f"{type(exc).__name__}: {exc}", "ratio": e.op.ratio,
                                "primary_speed_rpm": e.op.primary_speed_rpm,
                                "primary_torque_nm": e.op.primary_torque_nm, "variant": self.variant}
                    e.done_s = self.clock()
                self._idle.notify_all()
            if not self._closed:
                self._notify(e)
                self._pump()
            return
        res = {**res, "cached": False}
        if "warm_from_op" in e.extra and str(res.get("start", "")).startswith("warm"):
            res["warm_from"] = e.extra["warm_from_op"]
        self._write_cache(key, res, warm)
        with self._lock:
            e.result, e.done_s = res, self.clock()
            if warm is not None:
                self._warm.append((key, warm))
            self._busy = None
        self._notify(e)
        self._pump()

    def _notify(self, e: Entry) -> None:
        if self.on_result is not None and not e.prime:
            try:
                self.on_result(e.key, e.result)
            except Exception:  # noqa: BLE001  (a display callback must not stop the service)
                pass

    # --- disk ---------------------------------------------------------------------------------------
    def _read_cache(self, key: str) -> dict | None:
        if not self.use_cache:
            return None
        path = self.cache / f"{key}.json"
        try:
            return {**json.loads(path.read_text()), "cached": True}
        except (OSError, ValueError):
            return None  # absent or unreadable: solve (and overwrite)

    def _warm_dir(self) -> Path:
        return self.cache / "warm"

    def _write_cache(self, key: str, res: dict, warm: WarmState | None) -> None:
        if not self.use_cache:
            return
        try:
            self.cache.mkdir(parents=True, exist_ok=True)
            stored = {k: v for k, v in res.items() if k not in ("cached", "warm_from", "job_s")}
            tmp = self.cache / f"{key}.json.tmp"
            tmp.write_text(json.dumps(stored, default=float))
            tmp.replace(self.cache / f"{key}.json")  # atomic: a reader never sees half a file
        except OSError:
            return  # a read-only cache must not stop the overlay
        if warm is None:
            return
        try:
            d = self._warm_dir()
            d.mkdir(exist_ok=True)
            meta = {"case": asdict(warm.case), "op": asdict(warm.op), "variant": warm.variant,
                    "slip_threshold_m_s": warm.slip_threshold_m_s}
            name = f"{self._code[:16]}-{key[:24]}"
            tmp = d / f"{name}.tmp.npz"
            np.savez(tmp, t=warm.t, y=warm.y, p=warm.p, rms=np.asarray([] if warm.rms is None else warm.rms),
                     meta=np.asarray(json.dumps(meta)))
            tmp.replace(d / f"{name}.npz")
        except (OSError, TypeError, ValueError):
            pass  # only a warm start lost for the next session

    def _load_warm_states(self) -> None:
        """Read the solutions earlier sessions stored (same model code only: the state layout may change)."""
        from dyno.model.equations import Case

        d = self._warm_dir()
        try:
            files = sorted(d.glob(f"{self._code[:16]}-*.npz"), key=lambda p: p.stat().st_mtime)
            # Bound the directory: older model code's states are no use to this code, and past
            # KEEP_WARM_FILES the oldest of this code's go (a rig solves ~20-50 points a run).
            stale = [f for f in d.glob("*.npz") if not f.name.startswith(self._code[:16])]
            for f in stale + files[:-KEEP_WARM_FILES]:
                f.unlink(missing_ok=True)
            files = files[-MAX_WARM_FILES:]
        except OSError:
            return
        for f in files:
            if f.name.endswith(".tmp.npz"):
                continue
            try:
                with np.load(f) as z:
                    meta = json.loads(str(z["meta"]))
                    rms = z["rms"]
                    ws = WarmState(case=Case(**meta["case"]), t=z["t"], y=z["y"], p=z["p"],
                                   rms=rms if rms.size else None, op=OperatingPoint(**meta["op"]),
                                   variant=meta["variant"], slip_threshold_m_s=float(meta["slip_threshold_m_s"]))
            except Exception:  # noqa: BLE001  (a damaged file is only a lost warm start)
                continue
            self._warm.append((f"disk:{f.stem}", ws))
