"""Belt-model efficiency table for the simulated CVT.

The full belt model (:mod:`dyno.model`, thesis Table 6.1 belt on the tune's
drive geometry) is solved once on a grid of geometric ratios x primary torques
covering the simulated CVT's whole ratio range (0.54 .. 3.07), at the clamping
force the CVT tune puts on the belt there (:func:`tune_clamp_n`: flyweights
minus spring, Messick eq. 9.3, at :data:`TABLE_RPM`), by continuation: a cold
solve at ratio 1, 18 N m, warm starts outward in ratio at the reference
torque, then each other torque warm-started from the same ratio.  Without a
tune (the sim's closed-form CVT) the tension level is a fixed 100 N slack
tension.  Every result is stored in the
overlay's disk cache (:func:`dyno.model.cache_keys.point_key`, same JSON entries
as :func:`~dyno.model.overlay.predict_overlay` writes), so the table is
computed once per machine and read back in milliseconds afterwards.

A cell whose solve raises :class:`~dyno.errors.DidNotConverge` (or is cached as
failed) is marked failed and logged; the simulated CVT uses its simple loss
model in that cell (``BeltTable.ok`` is False there).

Lookup: PCHIP over ratio per torque, sampled on a dense ratio grid at build
time; at run time a bilinear lookup in that dense grid (a few microseconds,
called every 4 ms physics cell), clamped to the table's range.
"""

from __future__ import annotations

import contextlib
import contextvars

import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

#: Default grid: the simulated CVT's whole geometric ratio range (0.54, the overdrive stop of the 2019
#: logs, .. 3.07, the stock drive's geometric low stop 3.065) and four torques (the thrust ratio falls with
#: load: dyno.sim.belt_thrust).  Cells where the belt model finds gross slip at the tune's clamp are
#: failed cells (the loss model answers there; the CVT downshifts).
DEFAULT_RATIOS = (0.54, 0.62, 0.72, 0.82, 0.92, 1.0, 1.12, 1.25, 1.4, 1.55, 1.75, 1.95, 2.15, 2.4, 2.7, 3.07)
DEFAULT_TORQUES_NM = (3.0, 8.0, 13.0, 18.0)
REFERENCE_TORQUE_NM = 18.0
#: Engine speed of the table's clamp: the middle of the 3000-3300 rpm the stock tune holds on the
#: sim and the thesis logs (the flyweights' clamp goes as rpm^2: +-5 % over that band).
TABLE_RPM = 3150.0
SLACK_TENSION_N = 100.0
_DENSE = 200


@dataclass
class BeltTable:
    """Torque and speed efficiency of the belt model on a ratio x torque grid."""

    ratios: np.ndarray                 # ascending
    torques_nm: np.ndarray             # ascending
    eta_torque: np.ndarray             # (n_ratio, n_torque); NaN where failed
    eta_speed: np.ndarray
    ok: np.ndarray                     # bool, converged cells
    errors: dict = field(default_factory=dict)   # (ratio, torque) -> message
    build_s: float = 0.0
    solved: int = 0                    # cells solved now (not from the cache)
    rpm: float = TABLE_RPM             # engine speed of the cells (and of the tune's clamp)
    clamp_n: tuple = ()                # primary clamp per ratio (NaN: fixed slack tension)
    #: the belt's thrust ratio F_s,belt / F_p of the full model per cell (NaN where failed or not stored)
    kappa: np.ndarray | None = None
    _dense: tuple | None = None
    _dense_kappa: list | None = None

    def __post_init__(self):
        self._prepare()

    def _prepare(self):
        """Dense PCHIP samples over ratio per torque (failed cells excluded)."""
        from scipy.interpolate import PchipInterpolator

        r = self.ratios
        grid = np.linspace(r[0], r[-1], _DENSE + 1)
        et = np.full((grid.size, self.torques_nm.size), np.nan)
        es = np.full_like(et, np.nan)
        okd = np.zeros(et.shape, dtype=bool)
        for j in range(self.torques_nm.size):
            m = self.ok[:, j]
            if m.sum() >= 2:
                et[:, j] = PchipInterpolator(r[m], self.eta_torque[m, j], extrapolate=False)(grid)
                es[:, j] = PchipInterpolator(r[m], self.eta_speed[m, j], extrapolate=False)(grid)
            elif m.sum() == 1:
                k = int(np.argmax(m))
                near = np.isclose(grid, r[k])
                et[near, j] = self.eta_torque[k, j]
                es[near, j] = self.eta_speed[k, j]
            # a grid ratio between two good cells with a failed cell between them
            # is not trusted: it lies in a failed cell's neighbourhood
            for k in range(r.size):
                lo = r[k - 1] if k > 0 else r[0]
                hi = r[k + 1] if k + 1 < r.size else r[-1]
                if not m[k]:
                    et[(grid > lo) & (grid < hi), j] = np.nan
                    es[(grid > lo) & (grid < hi), j] = np.nan
            okd[:, j] = np.isfinite(et[:, j]) & np.isfinite(es[:, j])
        self._dense = (float(grid[0]), float(grid[-1]), grid.size - 1, et.tolist(), es.tolist(), okd.tolist())
        self._dense_kappa = None
        if self.kappa is not None:
            ek = np.full_like(et, np.nan)
            for j in range(self.torques_nm.size):
                m = np.isfinite(self.kappa[:, j])
                if m.sum() >= 2:
                    ek[:, j] = PchipInterpolator(r[m], self.kappa[m, j], extrapolate=False)(grid)
                for k in range(r.size):  # (as for the efficiencies: not across a failed cell)
                    if not m[k]:
                        ek[(grid > (r[k - 1] if k > 0 else r[0])) & (grid < (r[k + 1] if k + 1 < r.size else r[-1])), j] = np.nan
            # Where the full model finds gross slip (the clamp cannot carry that torque: a slipping clutch, whose
            # capacity dyno.sim.driven limits), the belt keeps the thrust ratio of the highest torque it carries
            # at that ratio; a ratio with no carried torque at all, its nearest neighbour's.
            for i in range(ek.shape[0]):
                for j in range(1, ek.shape[1]):
                    if not np.isfinite(ek[i, j]):
                        ek[i, j] = ek[i, j - 1]
            rows = np.flatnonzero(np.isfinite(ek[:, 0]))
            if rows.size:
                for i in np.flatnonzero(~np.isfinite(ek[:, 0])):
                    ek[i, :] = ek[rows[np.argmin(np.abs(rows - i))], :]
            self._dense_kappa = ek.tolist()
        span = float(grid[-1] - grid[0])
        self._inv_dr = (grid.size - 1) / span if span > 0.0 else 0.0
        self._tq = [float(t) for t in self.torques_nm]

    def lookup(self, ratio: float, torque_nm: float):
        """``(eta_torque, eta_speed)`` at a point, or None where the table has no answer.

        Ratio and torque are clamped to the table's range (no extrapolation).
        Pure Python (called every physics cell).
        """
        r0, r1, n, et, es, okd = self._dense
        tq = self._tq
        u = ((r0 if ratio < r0 else (r1 if ratio > r1 else ratio)) - r0) * self._inv_dr
        i = int(u)
        if i >= n:
            i = n - 1
        fr = u - i
        nt = len(tq)
        if nt == 1:
            if not (okd[i][0] and okd[i + 1][0]):
                return None
            a, b = et[i][0], es[i][0]
            return a + fr * (et[i + 1][0] - a), b + fr * (es[i + 1][0] - b)
        t = tq[0] if torque_nm < tq[0] else (tq[-1] if torque_nm > tq[-1] else torque_nm)
        j = 0
        while j < nt - 2 and t > tq[j + 1]:
            j += 1
        ft = (t - tq[j]) / (tq[j + 1] - tq[j])
        ri, rn = okd[i], okd[i + 1]
        if not (ri[j] and ri[j + 1] and rn[j] and rn[j + 1]):
            return None
        out = []
        for tab in (et, es):
            ti, tn = tab[i], tab[i + 1]
            lo = ti[j] + fr * (tn[j] - ti[j])
            hi = ti[j + 1] + fr * (tn[j + 1] - ti[j + 1])
            out.append(lo + ft * (hi - lo))
        return out[0], out[1]


    def lookup_kappa(self, ratio: float, torque_nm: float):
        """The full model's thrust ratio ``F_s,belt / F_p`` at a cell's clamp, or None (failed, or not stored).

        Clamped to the table's range like :meth:`lookup`; pure Python (called every ~0.1 s of sim time).
        """
        if self._dense_kappa is None:
            return None
        r0, r1, n, _, _, okd = self._dense
        tq, ek = self._tq, self._dense_kappa
        u = ((r0 if ratio < r0 else (r1 if ratio > r1 else ratio)) - r0) * self._inv_dr
        i = min(int(u), n - 1)
        fr = u - i
        if len(tq) == 1:
            a, b = ek[i][0], ek[i + 1][0]
            v = a + fr * (b - a)
            return v if v == v else None
        t = tq[0] if torque_nm < tq[0] else (tq[-1] if torque_nm > tq[-1] else torque_nm)
        j = 0
        while j < len(tq) - 2 and t > tq[j + 1]:
            j += 1
        ft = (t - tq[j]) / (tq[j + 1] - tq[j])
        lo = ek[i][j] + fr * (ek[i + 1][j] - ek[i][j])
        hi = ek[i][j + 1] + fr * (ek[i + 1][j + 1] - ek[i][j + 1])
        v = lo + ft * (hi - lo)
        return v if v == v else None  # (NaN: a failed cell nearby)

    def clamp_at(self, ratio: float) -> float:
        """The primary clamp (N) the cells at ``ratio`` were solved at (interpolated; NaN: slack tension)."""
        return float(np.interp(ratio, self.ratios, np.asarray(self.clamp_n, dtype=float)))


def _cache_entry(cache: Path, key: str):
    path = cache / f"{key}.json"
    if path.is_file():
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            return None
    return None


def _store(cache: Path, key: str, res: dict) -> None:
    try:
        cache.mkdir(parents=True, exist_ok=True)
        tmp = cache / f"{key}.json.tmp"
        tmp.write_text(json.dumps(res, default=float))
        tmp.replace(cache / f"{key}.json")
    except OSError:
        pass  # a read-only cache must not break the sim


def tune_clamp_n(tune, rpm: float, ratio: float) -> float:
    """Primary clamping force (N) the tune puts on the belt at a geometric ratio and engine speed.

    Flyweights minus spring (Messick eq. 9.3) at the primary radius the belt
    length gives for this ratio on the tune's drive.  The same function feeds
    the inverse of the overlay (:mod:`dyno.model.inverse`).
    """
    from dyno.model.inverse import clamp_from_tune

    return clamp_from_tune(tune, rpm)(ratio)


def build_belt_table(ratios=DEFAULT_RATIOS, torques_nm=DEFAULT_TORQUES_NM, *, cache_dir=None,
                     rpm: float = TABLE_RPM, slack_tension_n: float = SLACK_TENSION_N, tune=None,
                     time_limit_s: float = 30.0, solve=None) -> BeltTable:
    """Build (or read back from the overlay cache) the belt-model efficiency table.

    With ``tune`` every cell is solved at the tune's clamping force
    (:func:`tune_clamp_n` at ``rpm``) on the tune's drive geometry; without,
    at ``slack_tension_n`` on Table 6.1.
    ``solve(op, guess)`` replaces :func:`dyno.model.solution.solve_point` (tests).
    """
    from dyno.errors import MODEL_FAILURES, ConfigError
    from dyno.model.cache_keys import default_cache_dir, point_key
    from dyno.model.params import TABLE_6_1, OperatingPoint

    t0 = time.perf_counter()
    if tune is not None:
        from dyno.tuning.tune import model_params_for

        params = model_params_for(tune)
    else:
        params = TABLE_6_1
    variant, slip, tol = "corrected", 1e-4, 1e-3
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    ratios = np.array(sorted(float(r) for r in ratios))
    torques = np.array(sorted(float(t) for t in torques_nm))
    if solve is None:
        def solve(op, guess):
            # imported only on a cache miss: with a warm cache the sim never loads the solver
            from dyno.model.solution import solve_point

            return solve_point(params, op, variant=variant, slip_threshold_m_s=slip, tol=tol, guess=guess,
                               time_limit_s=time_limit_s)

    def op_of(r, t):
        if tune is not None:
            clamp = tune_clamp_n(tune, rpm, r)
            if not clamp > 0.0:
                raise ConfigError("<tune>", "primary", f"a positive clamp at {rpm:g} rpm, ratio {r:g} "
                                  f"(got {clamp:.0f} N: the flyweights do not overcome the spring)")
            return OperatingPoint(ratio=float(r), primary_speed_rpm=rpm, primary_torque_nm=float(t),
                                  slack_tension_n=None, primary_axial_force_n=clamp)
        return OperatingPoint(ratio=float(r), primary_speed_rpm=rpm, primary_torque_nm=float(t),
                              slack_tension_n=slack_tension_n)

    results: dict = {}
    solved = 0
    for r in ratios:
        for t in torques:
            e = _cache_entry(cache, point_key(params, op_of(r, t), "full", variant, slip, tol))
            if e is not None:
                results[(r, t)] = e

    # Continuation order: reference torque outward from ratio 1 (Table 6.1), then the others.
    t_ref = torques[int(np.argmin(np.abs(torques - REFERENCE_TORQUE_NM)))]
    k1 = int(np.argmin(np.abs(ratios - 1.0)))
    order = [(k, t_ref) for k in range(k1, ratios.size)] + [(k, t_ref) for k in range(k1 - 1, -1, -1)]
    order += [(k, t) for k in list(range(k1, ratios.size)) + list(range(k1 - 1, -1, -1)) for t in torques if t != t_ref]
    sols: dict = {}
    for k, t in order:
        r = ratios[k]
        if (r, t) in results:
            continue
        op = op_of(r, t)
        # warm start: the nearest solved ratio at this torque, else this ratio at t_ref, else cold
        same_t = [(abs(rr - r), rr) for (rr, tt) in sols if tt == t]
        nearest = sols[(min(same_t)[1], t)] if same_t else None
        cands = [c for c in (nearest, sols.get((r, t_ref))) if c is not None]
        cands = [c for m, c in enumerate(cands) if all(c is not d for d in cands[:m])] + [None]
        sol, err = None, None
        for guess in cands:   # a far neighbour can be a worse start than none: cold last
            try:
                sol = solve(op, guess)
                break
            except (*MODEL_FAILURES, ConfigError) as exc:   # infeasible input or gross slip: a failed cell too
                err = exc
        solved += 1
        if sol is None:
            res = {"converged": False, "tier": "full", "error": str(err),
                   "state": "gross_slip" if type(err).__name__ == "GrossSlip" else "failed"}
        else:
            s = sol.summary
            sols[(r, t)] = sol
            res = {"converged": True, "tier": "full", "efficiency": s["efficiency"],
                   "axial_force_n": s.get("axial_force_n"), "span_tension_n": s.get("span_tension_n"),
                   "residual_max": s.get("residual_max"), "slip_threshold_m_s": s.get("slip_threshold_m_s"),
                   "solve_s": s.get("solve_s")}
        res.update(ratio=op.ratio, primary_speed_rpm=op.primary_speed_rpm, primary_torque_nm=op.primary_torque_nm,
                   variant=variant)
        _store(cache, point_key(params, op, "full", variant, slip, tol), res)
        results[(r, t)] = res

    et = np.full((ratios.size, torques.size), np.nan)
    es = np.full_like(et, np.nan)
    kappa = np.full_like(et, np.nan)
    ok = np.zeros(et.shape, dtype=bool)
    errors = {}
    for a, r in enumerate(ratios):
        for b, t in enumerate(torques):
            res = results[(r, t)]
            eff = res.get("efficiency") or {}
            good = bool(res.get("converged")) and all(
                isinstance(eff.get(q), (int, float)) and math.isfinite(eff[q]) and 0.0 < eff[q] <= 1.0
                for q in ("torque", "speed"))
            f = res.get("axial_force_n") or {}
            if res.get("converged") and isinstance(f.get("primary"), (int, float)) and f["primary"] > 0 \
                    and isinstance(f.get("secondary"), (int, float)):
                # the thrust ratio of a converged cell, whatever its efficiencies (a speed "efficiency" a
                # little over 1 in overdrive is the belt's seating radius, not a failed solve)
                kappa[a, b] = f["secondary"] / f["primary"]
            if good:
                et[a, b], es[a, b], ok[a, b] = eff["torque"], eff["speed"], True
            else:
                errors[(float(r), float(t))] = res.get("error", f"unphysical efficiency {eff!r}")
                # recorded in BeltTable.errors; not a warning on every run's stderr (one-line outputs)
                log.info("belt table: ratio %.3f, %.1f N m did not converge, the loss model is used there: %s",
                         r, t, errors[(float(r), float(t))])
    return BeltTable(ratios=ratios, torques_nm=torques, eta_torque=et, eta_speed=es, ok=ok, errors=errors, kappa=kappa,
                     build_s=time.perf_counter() - t0, solved=solved, rpm=float(rpm),
                     clamp_n=tuple(float(op_of(r, torques[0]).primary_axial_force_n or math.nan) for r in ratios))


_TABLES: dict = {}
#: called with the tune's name (or None) before a table the cache does not hold is solved (a minute or two):
#: a command line says so on stderr instead of looking hung (a run's spec gives it, dyno.session.root.run_test sets it
#: for that run's context with :func:`announcing_builds`; a full-screen UI gives none)
_ON_BUILD: contextvars.ContextVar = contextvars.ContextVar("belt_table_on_build", default=None)


@contextlib.contextmanager
def announcing_builds(on_build):
    """Within the block (and the tasks it starts), ``on_build(tune name)`` is called before a table is solved."""
    token = _ON_BUILD.set(on_build)
    try:
        yield
    finally:
        _ON_BUILD.reset(token)


class _CacheMiss(Exception):
    """A cell the cache does not hold (raised past build_belt_table's model-failure handling)."""


def _cached_only(op, guess):
    raise _CacheMiss


def belt_table(cache_dir=None, tune=None) -> BeltTable:
    """The default table for ``tune`` (None: 100 N slack), built once per process (and once per
    machine via the cache).

    Concurrent processes (e.g. pytest-xdist workers) serialise on a lock file in
    the cache directory: the first builds, the others then read its entries.  A table
    whose every cell is cached is read without the lock (entries are written
    atomically), so a reader never waits for another process building another table.
    """
    from dyno.model.cache_keys import default_cache_dir

    key = (str(cache_dir), None if tune is None else json.dumps(tune.to_dict(), sort_keys=True, default=str))
    if key not in _TABLES:
        cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        try:
            _TABLES[key] = build_belt_table(cache_dir=cache, tune=tune, solve=_cached_only)
        except _CacheMiss:
            on_build = _ON_BUILD.get()
            if on_build is not None:
                on_build(getattr(tune, "name", None))
            _TABLES[key] = _build_locked(cache, tune)
        t = _TABLES[key]
        log.info("belt table: %d x %d cells, %d solved now, %d failed, %.2f s", t.ratios.size, t.torques_nm.size,
                 t.solved, int((~t.ok).sum()), t.build_s)
    return _TABLES[key]


def _build_locked(cache: Path, tune) -> BeltTable:
    """Build under the cache's lock file: concurrent builders wait, then read what the first wrote."""
    lock = None
    try:
        import fcntl

        cache.mkdir(parents=True, exist_ok=True)
        lock = open(cache / "belt_table.lock", "w")
        fcntl.flock(lock, fcntl.LOCK_EX)
    except (ImportError, OSError):
        lock = None  # no locking available: build anyway (entries are written atomically)
    try:
        return build_belt_table(cache_dir=cache, tune=tune)
    finally:
        if lock is not None:
            lock.close()
