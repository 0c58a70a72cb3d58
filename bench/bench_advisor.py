#!/usr/bin/env python3
"""The tune advisor against the simulated rig with parts that are not their labels.

Each scenario is a rig (world seed) with ``--sim-tune-deviation 0.1`` (every part's true values off its
labels within its own tolerance, dyno.sim.tune_deviation, the same part keeping its deviation across
trips), a starting tune and targets for the engagement plan's light-load engagement and shift-out: what a
hidden catalogue tune of <= 2 changes measures on that rig (:data:`SCENARIOS`). The loop a team runs:

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

The simulated rig has physics the advisor's relations leave out (docs/tuning.md "What the simulator
shares with the host"): its own clutch flank friction per world, the ramps' and helix's friction (the
up-shift figures sit above the frictionless balance), the full belt model's thrust ratio, and parts
deviating on fields the advisor does not calibrate.

Pass criteria (exit 1 when one fails, after the table): both targets within ±50 rpm in ≤ 2 advised trips
in ≥ 9/10 scenarios (``--quick``: its one scenario), and the measured figures within the advisor's
predicted ± U95 in ≥ 90 % of them (``--quick``: ≥ 75 % of its ≤ 4).  Each scenario's verdict says why a
miss missed.  ``--break-input RPM`` (a test of the criteria) adds RPM to every figure the advisor is
given: its input is wrong, so the bench must fail.
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

from dyno.session.root import RunSpec, run_test  # noqa: E402
from dyno.control.plans import plan_named  # noqa: E402
from dyno.errors import ConfigError  # noqa: E402
from dyno.sim.rig_params import RigParams  # noqa: E402
from dyno.tuning.advisor import advise  # noqa: E402
from dyno.tuning.advisor_model import load_run_data  # noqa: E402
from dyno.tuning.parts import apply_part, load_catalogue, match_parts  # noqa: E402
from dyno.tuning.tune import dumps_tune, load_tune  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TOL_RPM = 50.0
VERBOSE = False
REL = 0.1
BREAK_RPM = 0.0  # --break-input: a lie added to every figure the advisor reads
#: (starting tune, catalogue parts fitted to it first, the hidden tune's catalogue changes (<= 2)). The
#: targets are what the hidden tune measures on the scenario's rig (one engagement run before the loop, its
#: figures rounded to 10 rpm): reachable by a catalogue tune of <= 2 changes on that rig by construction,
#: whatever the rig's friction and parts are (the advisor never sees the hidden tune or the sim's truth).
SCENARIOS = (
    ("cvtech-stock", (), ("fw-3x240g",)),
    ("cvtech-stock", (), ("ps-900n-17.5k", "ss-190n@1")),
    ("heavy-flyweights", (), ("fw-3x252g", "ss-215n@1.4")),
    ("cvtech-stock", ("ss-165n@1",), ("ps-850n-16.5k",)),
    ("heavy-flyweights", (), ("ps-880n-17k", "hx-21deg")),
    ("cvtech-stock", ("fw-3x236g",), ("fw-3x260g", "ss-215n@1.4")),
    ("cvtech-stock", ("ps-975n-18.6k",), ("fw-3x220g", "ps-950n-18.2k")),
    ("heavy-flyweights", ("ss-115n@0.6",), ("fw-3x272g", "ss-165n@1")),
    ("cvtech-stock", ("hx-21deg",), ("ps-1000n-18.8k", "hx-25deg")),
    ("cvtech-stock", ("fw-3x232g", "ss-215n@1"), ("fw-3x224g", "ss-165n@1.4")),
    ("heavy-flyweights", ("ps-975n-18.6k",), ("ss-190n@0.6",)),
    ("cvtech-stock", ("ss-140n@1.4",), ("fw-3x244g", "ps-925n-17.8k")),
)


def _part(cat, pid: str):
    for p in cat:
        if p.id == pid:
            return p
    raise SystemExit(f"bench_advisor: catalogue part {pid!r} not in calibration/parts (a scenario names it)")


def engagement_run(tune, seed: int, world_seed: int, out: Path) -> dict:
    path = out.with_suffix(".toml")
    path.write_text(dumps_tune(tune))
    r = run_test(RunSpec(sim=True, seed=seed, out_dir=out, tune_path=path, plan=plan_named("engagement"),
                            sim_params=RigParams(cvt_tune_path=str(path), tune_deviation_rel=REL,
                                                 world_seed=world_seed, belt_efficiency_source="loss_model")))
    return r


def _hit(r: dict, tgt: dict) -> bool:
    return all(math.isfinite(r.get(f"{f}_rpm", math.nan)) and abs(r[f"{f}_rpm"] - v) <= TOL_RPM
               for f, v in tgt.items())


def _load(run_dir: Path):
    rd = load_run_data(run_dir)
    if BREAK_RPM:
        import dataclasses

        rd.figures = [dataclasses.replace(f, rpm=f.rpm + BREAK_RPM) for f in rd.figures]
    return rd


def verdict(res: dict, tgt: dict) -> str:
    """Why a scenario missed (or 'hit'): from the last advised trip's prediction and measurement."""
    if res["ok"]:
        return "hit" if res["trips"] <= 2 else f"hit in {res['trips']} trips"
    if res.get("why"):
        return res["why"]
    last = res.get("last")
    if not last:
        return "missed: no advised trip"
    pred, p_hit, f = last
    why = []
    for fig, v in tgt.items():
        m = f.get(f"{fig}_rpm", math.nan)
        if not math.isfinite(m):
            why.append(f"{fig} not measured ({f.get('state')}: {f.get('reason')})")
            continue
        if abs(m - v) <= TOL_RPM:
            continue
        pr = pred[fig]
        if abs(m - pr["rpm"]) > pr["u95_rpm"]:
            why.append(f"{fig} {m - v:+.0f} rpm off target, {m - pr['rpm']:+.0f} from the prediction "
                       f"(outside its U95 {pr['u95_rpm']:.0f}: the model missed)")
        else:
            why.append(f"{fig} {m - v:+.0f} rpm off target, within the prediction's U95 {pr['u95_rpm']:.0f} "
                       f"(the best tune's P(hit) {p_hit:.2f}: the calibration was not tight enough)")
    return "missed: " + "; ".join(why)


def advisor_loop(start, tgt: dict, world_seed: int, tmp: Path, cat, max_trips: int) -> dict:
    runs = []
    r = engagement_run(start, 1, world_seed, tmp / "adv-0")
    cover1 = cover2 = n_cov = 0
    try:
        runs.append(_load(tmp / "adv-0"))
    except ConfigError:  # the starting tune cannot be characterised on this rig (e.g. engages too high)
        print(f"    (starting run: {r['state']}: {r.get('reason')})", flush=True)
        return {"trips": 0, "ok": False, "cover1": 0, "cover2": 0, "n_cov": 0, "final": r, "changes": [],
                "why": f"missed: the starting run found no figures ({r['state']}: {r.get('reason')})"}
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
            runs.append(_load(tmp / f"adv-{trips}"))
        except ConfigError:  # the run found no engagement/shift-out (e.g. aborted): a trip that taught nothing
            print(f"    (scenario trip {trips}: {r['state']}: {r.get('reason')})", flush=True)
        for f in tgt:
            m = r.get(f"{f}_rpm", math.nan)
            if math.isfinite(m):
                n_cov += 1
                cover1 += abs(m - pred[f]["rpm"]) <= pred[f]["u_rpm"]
                cover2 += abs(m - pred[f]["rpm"]) <= pred[f]["u95_rpm"]
        last = (pred, a["ranked"][0]["p_within_tolerance"], r)
        if _hit(r, tgt):
            return {"trips": trips, "ok": True, "cover1": cover1, "cover2": cover2, "n_cov": n_cov,
                    "final": r, "changes": [p.id for p in best.changes]}
    return {"trips": trips, "ok": False, "cover1": cover1, "cover2": cover2, "n_cov": n_cov, "final": r,
            "changes": [p.id for p in best.changes], "last": last}


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
    ap.add_argument("--break-input", type=float, default=0.0, metavar="RPM",
                    help="add RPM to every figure the advisor reads (a wrong input: the criteria must fail)")
    a = ap.parse_args()
    global VERBOSE, BREAK_RPM
    VERBOSE, BREAK_RPM = a.verbose, a.break_input
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
    print("| # | start | targets eng / shift-out (the hidden tune) | advisor trips | advised parts | "
          "measured eng / shift-out | within ± u / ± U95 | rule-of-thumb trips | verdict | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    tot = {"ok2": 0, "ok": 0, "c1": 0, "c2": 0, "n": 0, "rot": [], "adv": []}
    try:
        for k, (start_name, fitted, hidden) in enumerate(SCENARIOS[:n]):
            if k + 1 < a.first or (a.only and k + 1 != a.only):
                continue
            t0 = time.monotonic()
            start = load_tune(ROOT / "calibration" / "tunes" / f"{start_name}.toml")
            for pid in fitted:
                start = apply_part(start, _part(cat, pid))
            target_tune = start
            for pid in hidden:
                target_tune = apply_part(target_tune, _part(cat, pid))
            world = 201 + k
            d = tmp / f"s{k}"
            d.mkdir()
            ref = engagement_run(target_tune, 99, world, d / "target")
            eng, so = (round(ref.get(f"{f}_rpm", math.nan) / 10.0) * 10.0 if math.isfinite(
                ref.get(f"{f}_rpm", math.nan)) else math.nan for f in ("engagement", "shift_out"))
            if not (math.isfinite(eng) and math.isfinite(so)):
                print(f"| {k + 1} | {start_name} | (hidden {'+'.join(hidden)} not characterised: {ref['state']}: "
                      f"{ref.get('reason')}) | - | - | - | - | - | counted as a miss | - |", flush=True)
                tot["adv"].append(math.inf)
                continue
            tgt = {"engagement": float(eng), "shift_out": float(so)}
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
            print(f"| {k + 1} | {start_name}{'+' + '+'.join(fitted) if fitted else ''} | {eng:.0f} / {so:.0f} "
                  f"({'+'.join(hidden)}) | "
                  f"{res['trips'] if res['ok'] else str(res['trips']) + ' (missed)'} | {' '.join(res['changes'])} | "
                  f"{f.get('engagement_rpm', math.nan):.0f} / {f.get('shift_out_rpm', math.nan):.0f} | "
                  f"{res['cover1']}/{res['n_cov']} / {res['cover2']}/{res['n_cov']} | "
                  f"{rot['trips'] if rot['ok'] or rot['trips'] == '-' else str(rot['trips']) + ' (missed)'} | "
                  f"{verdict(res, tgt)} | {time.monotonic() - t0:.0f} |", flush=True)
        ran = len(tot["adv"])
        print(f"\nadvisor: both targets within ±{TOL_RPM:.0f} rpm in ≤ 2 advised trips in {tot['ok2']}/{ran} "
              f"(in ≤ 3: {tot['ok']}/{ran})")
        fin = [t for t in tot["adv"] if math.isfinite(t)]
        rfin = [t for t in tot["rot"] if isinstance(t, (int, float)) and math.isfinite(t)]
        print(f"trips to the dyno after the first run: advisor mean {sum(fin) / max(len(fin), 1):.2f} "
              f"({len(fin)} reached); rule of thumb mean {sum(rfin) / max(len(rfin), 1):.2f} "
              f"({len(rfin)}/{ran} reached in ≤ 10)")
        if tot["n"]:
            print(f"coverage of the advisor's predictions ({tot['n']} measured figures): within ± u "
                  f"{tot['c1'] / tot['n']:.2f}, within ± U95 {tot['c2'] / tot['n']:.2f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    ran = len(tot["adv"])
    need_hits = ran if a.quick else math.ceil(0.9 * ran)
    need_cov = 0.75 if a.quick else 0.90
    cov = tot["c2"] / tot["n"] if tot["n"] else 0.0
    fails = []
    if tot["ok2"] < need_hits:
        fails.append(f"within ±{TOL_RPM:.0f} rpm in ≤ 2 trips in {tot['ok2']}/{ran} < {need_hits}/{ran}")
    if cov < need_cov:
        fails.append(f"U95 coverage {cov:.2f} < {need_cov:.2f}")
    print(f"criteria: ≥ {need_hits}/{ran} scenarios within ±{TOL_RPM:.0f} rpm in ≤ 2 trips, U95 coverage ≥ "
          f"{need_cov:.2f}: " + ("PASS" if not fails else "FAIL (" + "; ".join(fails) + ")"))
    if fails:
        sys.exit(1)


if __name__ == "__main__":
    main()
