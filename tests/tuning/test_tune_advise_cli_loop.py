"""The whole loop as a tuner runs it, on a simulated rig with physics the advisor does not assume (issue 38):

1. ``dyno run --sim --headless --json --plan engagement --sim-tune-deviation 0.1`` on the stock tune;
2. ``dyno tune advise RUN --target engagement=E --target shift_out=S`` for targets a catalogue tune of <= 2
   changes reaches on that rig (what that hidden tune measures there; the advisor never sees it);
3. ``dyno run ... --tune`` the advised tune; advise again on both runs if it missed.

Both figures must be within ±75 rpm after <= 2 advised tunes.  The rig's friction, thrust ratio and parts
are its own (dyno.sim.cvt_friction, dyno.sim.belt_thrust, dyno.sim.tune_deviation).  Slow (real processes,
a belt table per advised tune): the issue's must-show, kept to one rig.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

from dyno.session.root import RunSpec, run_test
from dyno.control.plans import plan_named
from dyno.sim.rig_params import RigParams
from dyno.tuning.parts import apply_part, load_catalogue
from dyno.tuning.tune import dumps_tune, load_tune

STOCK = Path("calibration/tunes/cvtech-stock.toml").resolve()
WORLD = 31
HIDDEN = ("fw-3x260g", "ss-215n@1.4")  # the catalogue tune whose figures on this rig are the targets
TOL_RPM = 75.0


def _dyno(*args, env, timeout=900):
    p = subprocess.run([sys.executable, "-m", "dyno", *args], capture_output=True, text=True, timeout=timeout,
                       env={**os.environ, **env}, stdin=subprocess.DEVNULL)
    assert p.returncode == 0, f"dyno {' '.join(args)}: exit {p.returncode}\n{p.stderr[-2000:]}"
    return json.loads(p.stdout)


def _run(tune: Path, seed: int, out: Path, env) -> dict:
    return _dyno("run", "--sim", "--headless", "--json", "--plan", "engagement", "--sim-tune-deviation", "0.1",
                 "--sim-world-seed", str(WORLD), "--seed", str(seed), "--tune", str(tune), "--out", str(out),
                 env=env)


def _miss(r: dict, tgt: dict) -> float:
    return max(abs(r.get(f"{f}_rpm", math.nan) - v) if math.isfinite(r.get(f"{f}_rpm", math.nan)) else math.inf
               for f, v in tgt.items())


def test_stock_run_advise_run_reaches_targets_within_75_rpm_in_two_advised_tunes(tmp_path):
    env = {"DYNO_RUNS_DIR": str(tmp_path / "runs")}
    cat_dir = tmp_path / "parts"  # the shipped catalogue but the team's +-2 % example part
    cat_dir.mkdir()
    for f in Path("calibration/parts").glob("*.toml"):
        if not f.name.startswith("team-"):
            shutil.copy(f, cat_dir / f.name)
    cat = load_catalogue(cat_dir)
    hidden = load_tune(STOCK)
    for pid in HIDDEN:
        hidden = apply_part(hidden, next(p for p in cat if p.id == pid))
    (tmp_path / "hidden.toml").write_text(dumps_tune(hidden))
    ref = run_test(RunSpec(sim=True, seed=9, out_dir=tmp_path / "hidden", tune_path=tmp_path / "hidden.toml",
                              plan=plan_named("engagement"),
                              sim_params=RigParams(cvt_tune_path=str(tmp_path / "hidden.toml"), tune_deviation_rel=0.1,
                                                   world_seed=WORLD, belt_efficiency_source="loss_model")))
    tgt = {f: round(ref[f"{f}_rpm"] / 10.0) * 10.0 for f in ("engagement", "shift_out")}

    runs = [tmp_path / "runs" / "r0"]
    r = _run(STOCK, 1, runs[0], env)
    assert _miss(r, tgt) > TOL_RPM, (r.get("engagement_rpm"), r.get("shift_out_rpm"), tgt)  # something to advise
    for trip in (1, 2):
        adv = _dyno("tune", "advise", *map(str, runs), "--target", f"engagement={tgt['engagement']:.0f}",
                    "--target", f"shift_out={tgt['shift_out']:.0f}", "--catalogue", str(cat_dir),
                    "--out", str(tmp_path / f"advice{trip}"), "--json", env=env)
        runs.append(tmp_path / "runs" / f"r{trip}")
        r = _run(Path(adv["tunes"][0]["tune_file"]), 1 + trip, runs[-1], env)
        if _miss(r, tgt) <= TOL_RPM:
            break
    assert _miss(r, tgt) <= TOL_RPM, (trip, r.get("engagement_rpm"), r.get("shift_out_rpm"), tgt)
