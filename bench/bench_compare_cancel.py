"""Does ``dyno compare``'s stated difference uncertainty ``U_d`` cover the true difference?

Run as ``python bench/bench_uncertainty.py --compare``.

Each world seed is one simulated rig (its engine, torque sensor, drawn day: :mod:`dyno.sim.world`).  On it two
runs of the short speed-hold plan: the stock tune and the heavy flyweights (a real change of efficiency and of
engine speed, ~220 rpm, so the map's error does not cancel exactly).  Even worlds measure both on the same day,
odd worlds the heavy tune on another drawn day.  The rig has a BME280 ("air known"); each run is also
re-processed with no air ("uncorrected", :func:`dyno.runlog.replay.replay` with ``Ambient()``).  Pairs:

* ``known``: both runs corrected to their air — calibration, map and air all residual;
* ``uncorrected``: neither — the air does not cancel (stated: each run's plausible-day term);
* ``mixed``: the stock run corrected, the heavy one not.

Per pair :func:`dyno.library.compare.compare` gives ``d``, ``U_d`` and the truth's difference (``efficiency_true``
interpolated the same way).  Printed per case and day: pairs, grid points, coverage of ``|d − d_true| ≤ U_d``
(over grid points, and per pair at its middle grid point: the systematic part is one draw per pair), the
normalised error's sd ``(d − d_true)/(U_d/1.96)``, the mean ``U_d`` and the mean of the two runs' own ``u95``.
"""

from __future__ import annotations

import math
import statistics
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TUNES = REPO / "calibration" / "tunes"


def _other_day(world: int) -> tuple[float, float, float]:
    """A second plausible day for the odd worlds (as dyno.sim.world.draw_day, its own stream)."""
    import numpy as np

    rng = np.random.default_rng([world, 0xDA7])
    alt = rng.uniform(0.0, 1500.0)
    return (float(rng.uniform(5.0, 35.0)), float(101.325 * (1.0 - 2.25577e-5 * alt) ** 5.25588),
            float(rng.uniform(20.0, 80.0)))


def _as_compared(out: Path, name: str, uncorrected: bool) -> dict:
    """A run as ``compare`` takes it; ``uncorrected``: re-processed with no air, its meta saying so."""
    from dyno.analysis.air import Ambient, uncorrected_air_rel_u
    from dyno.library.summary import read_run_files, run_row
    from dyno.runlog.replay import replay

    files = read_run_files(out)
    meta, points = files["meta"], [d for d in files["documents"] if d.get("type") == "point"]
    if uncorrected:
        points = replay(out, ambient=Ambient())["points"]
        meta = {**meta, "ambient": Ambient().to_dict(),
                "uncertainty": {**meta["uncertainty"], "air_rel": uncorrected_air_rel_u()}}
    return {"name": name, "row": run_row(files, str(out)), "points": points, "meta": meta, "tune": None}


def one_world(world: int, tmp: str, rig_path: str, plan_path: str) -> dict:
    """Two runs on one rig (stock, heavy flyweights) and the three pairs' coverage records."""
    from dyno.session.root import RunSpec, run_test
    from dyno.control.plans import plan_named
    from dyno.library.compare import compare
    from dyno.sim.rig_params import RigParams

    same_day = world % 2 == 0
    outs = {}
    for k, (tune, day) in {"A": ("cvtech-stock", None),
                           "B": ("heavy-flyweights", None if same_day else _other_day(world))}.items():
        out = Path(tmp) / f"w{world}{k}"
        tune_path = TUNES / f"{tune}.toml"
        params = RigParams(cvt_tune_path=str(tune_path), world_seed=world, ambient_day=day)
        run_test(RunSpec(sim=True, seed=10_000 + 2 * world + (k == "B"), out_dir=out, rig_path=Path(rig_path),
                            plan=plan_named(plan_path), tune_path=tune_path, sim_params=params))
        outs[k] = out
    pairs = []
    for case, (unc_a, unc_b) in {"known": (False, False), "uncorrected": (True, True), "mixed": (False, True)}.items():
        try:
            res = compare([_as_compared(outs["A"], "A", unc_a), _as_compared(outs["B"], "B", unc_b)])
        except ValueError as exc:
            pairs.append({"case": case, "error": str(exc)})
            continue
        q = res["differences"][0]["quantities"]["efficiency"]
        own = [p.get("efficiency_u95") for p in _as_compared(outs["A"], "A", unc_a)["points"]
               + _as_compared(outs["B"], "B", unc_b)["points"]]
        rows = [(d, t, u) for d, t, u in zip(q["difference"], q.get("truth_difference") or (), q["difference_u95"])
                if d is not None and t is not None and u is not None]
        pairs.append({"case": case, "same_day": same_day, "rows": rows,
                      "status": {k: v["status"] for k, v in res["differences"][0]["terms"].items()},
                      "own_u95": statistics.fmean(x for x in own if isinstance(x, float) and math.isfinite(x))})
    return {"world": world, "pairs": pairs}


def summarise(worlds: list[dict]) -> list[dict]:
    out = []
    for case in ("known", "uncorrected", "mixed"):
        for same in (True, False):
            ps = [p for w in worlds for p in w["pairs"] if p["case"] == case and p.get("same_day") == same
                  and p.get("rows")]
            rows = [r for p in ps for r in p["rows"]]
            if not rows:
                continue
            z = [(d - t) / (u / 1.96) for d, t, u in rows]
            mids = [p["rows"][len(p["rows"]) // 2] for p in ps]
            out.append({"case": case, "day": "same" if same else "different", "pairs": len(ps), "points": len(rows),
                        "coverage": sum(abs(d - t) <= u for d, t, u in rows) / len(rows),
                        "coverage_per_pair": sum(abs(d - t) <= u for d, t, u in mids) / len(mids),
                        "z_sd": statistics.pstdev(z), "mean_u95": statistics.fmean(u for *_, u in rows),
                        "mean_abs_true_d": statistics.fmean(abs(t) for _, t, _ in rows),
                        "mean_own_u95": statistics.fmean(p["own_u95"] for p in ps),
                        "status": ps[0]["status"]})
    return out


def run(worlds: list[int], jobs: int, tmp: str, rig_path: str, plan_path: str) -> list[dict]:
    from concurrent.futures import ProcessPoolExecutor

    n = len(worlds)
    if jobs > 1:
        with ProcessPoolExecutor(jobs) as pool:
            return list(pool.map(one_world, worlds, [tmp] * n, [rig_path] * n, [plan_path] * n))
    return [one_world(w, tmp, rig_path, plan_path) for w in worlds]


def print_table(rows: list[dict]) -> None:
    print(f"{'case':<12}{'day':<10}{'pairs':>6}{'points':>7}{'coverage':>9}{'per pair':>9}{'z sd':>6}"
          f"{'U_d pp':>8}{'|Δtrue| pp':>11}{'own u95 pp':>11}  terms")
    for r in rows:
        st = ", ".join(f"{k} {v}" for k, v in r["status"].items() if k != "statistical")
        print(f"{r['case']:<12}{r['day']:<10}{r['pairs']:>6}{r['points']:>7}{r['coverage']:>9.3f}"
              f"{r['coverage_per_pair']:>9.3f}{r['z_sd']:>6.2f}{100 * r['mean_u95']:>8.2f}"
              f"{100 * r['mean_abs_true_d']:>11.2f}{100 * r['mean_own_u95']:>11.2f}  {st}")


if __name__ == "__main__":  # the same bench as `bench_uncertainty.py --compare` (this module is its worker)
    import sys

    sys.path.insert(0, str(REPO / "bench"))
    from bench_uncertainty import main

    raise SystemExit(main(["--compare", *sys.argv[1:]]))
