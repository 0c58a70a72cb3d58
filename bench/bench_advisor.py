#!/usr/bin/env python3
"""The tune advisor against the simulated rig with parts that are not their labels.

Each scenario is a rig (world seed) with ``--sim-tune-deviation 0.1`` (every part's true flyweight mass,
spring preload and rate, helix angle within ±10 % of its label, the same part keeping its deviation
across trips), a starting tune and targets for the engagement plan's light-load engagement and
shift-out. The loop a team runs:

    engagement run -> dyno tune advise (runs so far) -> fit the #1 tune's parts -> engagement run -> ...

until both figures are within ±50 rpm (at most 3 advised trips are run; "≤ 2" is the issue's bar). Beside
it, a one-part-at-a-time rule-of-thumb tuner following the tuning guides ("more flyweight weight =
lower rpm": the flyweights set the shift-out; "a stiffer primary spring engages higher": the primary
spring sets the engagement; "a stiffer secondary spring shifts higher": once the engagement is right),
one catalogue step per ~40 rpm of miss (at most 3 steps), one part per
trip, the part with the larger miss first, up to 10 trips. Also the advisor's coverage: how often the
measured figure falls within the predicted ± u (k = 1) and ± U95 (k = 2).

The sim's efficiency here is its loss model (``belt_efficiency_source="loss_model"``): the belt-model
table is built per labelled tune (~90 s each) and the engagement plan's figures depend on the clamp,
not on the belt's efficiency share.

    python bench/bench_advisor.py [--scenarios 10] [--quick]

``--quick`` (CI's smoke run): one scenario, the advisor's loop only, at most 2 advised trips.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dyno.app import RunOptions, run_test  # noqa: E402
from dyno.control.plans import plan_named  # noqa: E402
from dyno.errors import ConfigError  # noqa: E402
from dyno.sim.physics import RigParams  # noqa: E402
from dyno.tuning.advisor import advise  # noqa: E402
from dyno.tuning.advisor_model import load_run_data  # noqa: E402
from dyno.tuning.parts import apply_part, load_catalogue, match_parts  # noqa: E402
from dyno.tuning.tune import dumps_tune, load_tune  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TOL_RPM = 50.0
VERBOSE = False
REL = 0.1
#: (starting tune, catalogue parts fitted to it first, engagement target, shift-out target). Engagement
#: targets stay <= ~2,170 rpm: the plan's loaded ramps engage ~40 rpm higher, and a clutch still slipping
#: at 2,300 rpm trips the rig's "the secondary must turn" check (docs/control.md); a 2,200 rpm target
#: aborted both advised trips that way (measured, then moved to 2,160).
SCENARIOS = (
    ("cvtech-stock", (), 2100, 2750),
    ("cvtech-stock", (), 2050, 2550),
    ("heavy-flyweights", (), 2150, 2700),
    ("cvtech-stock", ("ss-250n@1",), 2160, 2650),
    ("heavy-flyweights", (), 2000, 2600),
    ("cvtech-stock", ("fw-3x240g",), 2150, 2850),
    ("cvtech-stock", ("ps-900n-17.5k",), 2120, 2620),
    ("heavy-flyweights", ("ss-175n@0.6",), 2080, 2800),
    ("cvtech-stock", ("hx-36deg",), 2180, 2720),
    ("cvtech-stock", ("fw-3x236g", "ss-225n@1"), 2060, 2680),
    ("heavy-flyweights", ("ps-975n-18.6k",), 2170, 2780),
    ("cvtech-stock", ("ss-150n@1.4",), 2130, 2580),
)


def engagement_run(tune, seed: int, world_seed: int, out: Path) -> dict:
    path = out.with_suffix(".toml")
    path.write_text(dumps_tune(tune))
    r = run_test(RunOptions(sim=True, seed=seed, out_dir=out, tune_path=path, plan=plan_named("engagement"),
                            sim_params=RigParams(cvt_tune_path=str(path), tune_deviation_rel=REL,
                                                 world_seed=world_seed, belt_efficiency_source="loss_model")))
    return r


def _hit(r: dict, tgt: dict) -> bool:
    return all(math.isfinite(r.get(f"{f}_rpm", math.nan)) and abs(r[f"{f}_rpm"] - v) <= TOL_RPM
               for f, v in tgt.items())


def advisor_loop(start, tgt: dict, world_seed: int, tmp: Path, cat, max_trips: int) -> dict:
    runs = []
    r = engagement_run(start, 1, world_seed, tmp / "adv-0")
    cover1 = cover2 = n_cov = 0
    try:
        runs.append(load_run_data(tmp / "adv-0"))
    except ConfigError:  # the starting tune cannot be characterised on this rig (e.g. engages too high)
        print(f"    (starting run: {r['state']}: {r.get('reason')})", flush=True)
        return {"trips": 0, "ok": False, "cover1": 0, "cover2": 0, "n_cov": 0, "final": r, "changes": []}
    trips = 0
    if _hit(r, tgt):  # the start already meets them: nothing to advise
        return {"trips": 0, "ok": True, "cover1": 0, "cover2": 0, "n_cov": 0, "final": r, "changes": []}
    while trips < max_trips:
        a = advise(runs, cat, tgt, tolerance_rpm=TOL_RPM, top=1)
        best = a["_candidates"][0]
        pred = a["ranked"][0]["predicted"]
        trips += 1
        r = engagement_run(best.tune, 1 + trips, world_seed, tmp / f"adv-{trips}")
        if VERBOSE:
            print(f"    trip {trips}: {[p.id for p in best.changes]} p_hit {a['ranked'][0]['p_within_tolerance']:.2f} "
                  + " ".join(f"{f} {pred[f]['rpm']:.0f}±{pred[f]['u_rpm']:.0f} -> {r.get(f + '_rpm', math.nan):.0f}"
                             for f in tgt), flush=True)
        try:
            runs.append(load_run_data(tmp / f"adv-{trips}"))
        except ConfigError:  # the run found no engagement/shift-out (e.g. aborted): a trip that taught nothing
            print(f"    (scenario trip {trips}: {r['state']}: {r.get('reason')})", flush=True)
        for f in tgt:
            m = r.get(f"{f}_rpm", math.nan)
            if math.isfinite(m):
                n_cov += 1
                cover1 += abs(m - pred[f]["rpm"]) <= pred[f]["u_rpm"]
                cover2 += abs(m - pred[f]["rpm"]) <= pred[f]["u95_rpm"]
        if _hit(r, tgt):
            return {"trips": trips, "ok": True, "cover1": cover1, "cover2": cover2, "n_cov": n_cov,
                    "final": r, "changes": [p.id for p in best.changes]}
    return {"trips": trips, "ok": False, "cover1": cover1, "cover2": cover2, "n_cov": n_cov, "final": r,
            "changes": []}


def _step(cat, tune, kind: str, key, direction: int, steps: int):
    """The catalogue part ``steps`` steps from the current one along ``key`` (a rule of thumb's 'next size')."""
    cur = match_parts(tune, cat)[kind]
    parts = sorted((p for p in cat if p.kind == kind and not p.id.startswith("team-")), key=key)
    if cur not in parts:
        return None  # a part no catalogue lists: the guide has no 'next size'
    i = parts.index(cur)
    j = min(max(i + direction * steps, 0), len(parts) - 1)
    return None if j == i else apply_part(tune, parts[j])


def rule_of_thumb(start, tgt: dict, world_seed: int, tmp: Path, cat, max_trips: int = 10) -> dict:
    tune = start
    r = engagement_run(tune, 1, world_seed, tmp / "rot-0")
    for trip in range(1, max_trips + 1):
        miss = {f: r.get(f"{f}_rpm", math.nan) - v for f, v in tgt.items()}
        order = sorted(miss, key=lambda f: -abs(miss[f]) if math.isfinite(miss[f]) else 0)
        new = None
        for f in order:
            if abs(miss[f]) <= TOL_RPM:
                continue
            steps = min(3, max(1, round(abs(miss[f]) / 40.0)))
            up = miss[f] > 0  # the figure is too high
            fly = ("flyweights", lambda p: p.value("mass_each_kg"), 1 if up else -1)  # heavier: lower rpm
            sec = ("secondary_spring", lambda p: (p.value("preload_n"), p.value("torsion_preload_nm")),
                   -1 if up else 1)  # stiffer secondary: higher shift rpm
            prim = ("primary_spring", lambda p: p.value("force_at_full_shift_n", 0.0), -1 if up else 1)
            if f == "shift_out":  # flyweights; the secondary once the engagement is right (the guides)
                options = [sec, fly] if abs(miss.get("engagement", 0.0)) <= TOL_RPM else [fly, sec]
            else:  # a stiffer primary spring engages higher
                options = [prim, fly]
            for kind, key, direction in options:
                new = _step(cat, tune, kind, key, direction, steps)
                if new is not None:
                    break
            if new is not None:
                break
        if new is None:
            return {"trips": trip - 1, "ok": _hit(r, tgt)}
        tune = new
        r = engagement_run(tune, 1 + trip, world_seed, tmp / f"rot-{trip}")
        if _hit(r, tgt):
            return {"trips": trip, "ok": True}
    return {"trips": max_trips, "ok": False}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenarios", type=int, default=10)
    ap.add_argument("--first", type=int, default=1, help="start at this scenario (1-based)")
    ap.add_argument("--only", type=int, default=0, help="run this scenario alone (1-based)")
    ap.add_argument("--verbose", action="store_true", help="each advised trip: parts, predicted ± u, measured")
    ap.add_argument("--no-baseline", action="store_true", help="the advisor's loop only")
    ap.add_argument("--quick", action="store_true", help="CI smoke run: one scenario, the advisor only")
    a = ap.parse_args()
    global VERBOSE
    VERBOSE = a.verbose
    n = 1 if a.quick else min(a.scenarios, len(SCENARIOS))
    tmp = Path(tempfile.mkdtemp(prefix="bench_adv_"))
    # the shipped catalogue without the team's example part: it states +-2 % (weighed), but the sim draws
    # every part within +-REL, so on this rig that part would not be what its tolerance says
    (tmp / "parts").mkdir()
    for f in (ROOT / "calibration" / "parts").glob("*.toml"):
        if not f.name.startswith("team-"):
            shutil.copy(f, tmp / "parts" / f.name)
    cat = load_catalogue(tmp / "parts")
    print(f"--sim-tune-deviation {REL}, targets within ±{TOL_RPM:.0f} rpm; catalogue steps: flyweights 4 g per "
          "weight (~20 rpm), primary springs ~25-40 N at full shift (~25-40 rpm of engagement), secondary "
          "springs 25 N x 3 torsion positions (~10-25 rpm of shift-out)")
    print("| # | start | targets eng / shift-out | advisor trips | advised parts | measured eng / shift-out | "
          "within ± u / ± U95 | rule-of-thumb trips | wall s |")
    print("|---|---|---|---|---|---|---|---|---|")
    tot = {"ok2": 0, "ok": 0, "c1": 0, "c2": 0, "n": 0, "rot": [], "adv": []}
    try:
        for k, (start_name, fitted, eng, so) in enumerate(SCENARIOS[:n]):
            if k + 1 < a.first or (a.only and k + 1 != a.only):
                continue
            t0 = time.monotonic()
            start = load_tune(ROOT / "calibration" / "tunes" / f"{start_name}.toml")
            for pid in fitted:
                start = apply_part(start, next(p for p in cat if p.id == pid))
            tgt = {"engagement": float(eng), "shift_out": float(so)}
            world = 201 + k
            d = tmp / f"s{k}"
            d.mkdir()
            res = advisor_loop(start, tgt, world, d, cat, 2 if a.quick else 3)
            tot["ok2"] += res["ok"] and res["trips"] <= 2
            tot["ok"] += res["ok"]
            tot["c1"] += res["cover1"]
            tot["c2"] += res["cover2"]
            tot["n"] += res["n_cov"]
            tot["adv"].append(res["trips"] if res["ok"] else math.inf)
            rot = ({"trips": "-", "ok": False} if a.quick or a.no_baseline
                   else rule_of_thumb(start, tgt, world, d, cat))
            tot["rot"].append(rot["trips"] if rot["ok"] else math.inf)
            f = res["final"]
            print(f"| {k + 1} | {start_name}{'+' + '+'.join(fitted) if fitted else ''} | {eng} / {so} | "
                  f"{res['trips'] if res['ok'] else str(res['trips']) + ' (missed)'} | {' '.join(res['changes'])} | "
                  f"{f.get('engagement_rpm', math.nan):.0f} / {f.get('shift_out_rpm', math.nan):.0f} | "
                  f"{res['cover1']}/{res['n_cov']} / {res['cover2']}/{res['n_cov']} | "
                  f"{rot['trips'] if rot['ok'] or rot['trips'] == '-' else str(rot['trips']) + ' (missed)'} | "
                  f"{time.monotonic() - t0:.0f} |", flush=True)
        print(f"\nadvisor: both targets within ±{TOL_RPM:.0f} rpm in ≤ 2 advised trips in {tot['ok2']}/{n} "
              f"(in ≤ 3: {tot['ok']}/{n})")
        fin = [t for t in tot["adv"] if math.isfinite(t)]
        rfin = [t for t in tot["rot"] if isinstance(t, (int, float)) and math.isfinite(t)]
        print(f"trips to the dyno after the first run: advisor mean {sum(fin) / max(len(fin), 1):.2f} "
              f"({len(fin)} reached); rule of thumb mean {sum(rfin) / max(len(rfin), 1):.2f} "
              f"({len(rfin)}/{n} reached in ≤ 10)")
        if tot["n"]:
            print(f"coverage of the advisor's predictions ({tot['n']} measured figures): within ± u "
                  f"{tot['c1'] / tot['n']:.2f}, within ± U95 {tot['c2'] / tot['n']:.2f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
