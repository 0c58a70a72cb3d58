"""--sim-tune-deviation: the simulated CVT's parts are not their labels, each part keeps its own
deviation on the same rig (world seed) across runs, and the sim's physics runs on the true parts."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from dyno.sim.physics import RigModel
from dyno.sim.rig_params import RigParams
from dyno.sim.tune_deviation import deviate_tune
from dyno.tuning.tune import load_tune

STOCK = "calibration/tunes/cvtech-stock.toml"
HEAVY = "calibration/tunes/heavy-flyweights.toml"


def _model(seed, tune=STOCK, **kw):
    return RigModel(RigParams(cvt_tune_path=tune, tune_deviation_rel=0.1, belt_efficiency_source="loss_model",
                              **kw), seed=seed)


def _parts(model):
    return {p["kind"]: p for p in model.world.tune_parts}


def test_each_part_deviates_within_rel_and_keeps_it_on_the_same_rig():
    from dyno.tuning.parts import DEVIATED

    a, b = _model(1, world_seed=7), _model(2, world_seed=7)  # one rig measured twice
    c = _model(1, world_seed=8)                              # another rig
    pa, pb, pc = _parts(a), _parts(b), _parts(c)
    assert set(pa) == {"flyweights", "primary_spring", "secondary_spring", "helix"}
    devs = [v["deviation_rel"] for p in pa.values() for v in p.values() if isinstance(v, dict) and "deviation_rel" in v]
    assert len(devs) == 8 and all(abs(d) <= 0.1 for d in devs) and len(set(devs)) == 8
    # the sim deviates more than the advisor calibrates (not the advisor's prior's fields alone)
    sim_fields = {(k, f) for k, p in pa.items() for f, v in p.items() if isinstance(v, dict)}
    advisor_fields = {(k, f) for k, fs in DEVIATED.items() for f in fs}
    assert advisor_fields < sim_fields and {("flyweights", "radius_m"), ("helix", "radius_m"),
                                            ("secondary_spring", "torsion_rate_nm_per_rad")} <= sim_fields
    assert abs(pa["flyweights"]["radius_m"]["offset_m"]) <= 0.0005
    assert pa == pb
    assert all(pa[k] != pc[k] for k in pa)
    # the physics is the true parts': the model's tune carries the drawn values
    t = a.tune_true
    assert t.flyweights.mass_each_kg == pytest.approx(pa["flyweights"]["mass_each_kg"]["true"])
    assert t.primary_spring.rate_n_per_m == pytest.approx(pa["primary_spring"]["rate_n_per_m"]["true"])
    assert t.helix.angle_from_axis_deg == pytest.approx(pa["helix"]["angle_from_axis_deg"]["true"])


def test_a_swapped_part_brings_its_own_deviation_the_others_keep_theirs():
    stock, heavy = _parts(_model(3, world_seed=5)), _parts(_model(3, HEAVY, world_seed=5))
    assert stock["flyweights"]["mass_each_kg"]["deviation_rel"] != heavy["flyweights"]["mass_each_kg"]["deviation_rel"]
    for kind in ("primary_spring", "secondary_spring", "helix"):
        assert stock[kind] == heavy[kind]


def test_a_reclocked_secondary_spring_is_the_same_spring():
    """Moving the secondary spring to another torsion position is a setting, not another spring: its axial
    preload and rate keep their deviation (the sim's truth, and the advisor's calibration identity)."""
    from dyno.tuning.parts import part_identity

    tune = load_tune(STOCK)
    moved = tune.with_changes(**{"secondary_spring.torsion_preload_nm": 1.4})
    other = tune.with_changes(**{"secondary_spring.preload_n": 165.0})
    (_, rec), (_, rec_moved), (_, rec_other) = (deviate_tune(t, 0.1, 5) for t in (tune, moved, other))
    sec = [{k: v for k, v in r.items()} for rr in (rec, rec_moved, rec_other) for r in rr
           if r["kind"] == "secondary_spring"]
    assert sec[0]["preload_n"] == sec[1]["preload_n"] and sec[0]["rate_n_per_m"] == sec[1]["rate_n_per_m"]
    assert sec[2]["preload_n"]["deviation_rel"] != sec[0]["preload_n"]["deviation_rel"]
    assert part_identity(tune, "secondary_spring") == part_identity(moved, "secondary_spring")
    assert part_identity(tune, "secondary_spring", with_settings=True) != part_identity(moved, "secondary_spring",
                                                                                        with_settings=True)


def test_washers_on_a_flyweight_body_keep_the_bodys_deviation():
    """A 232 g set made of the stock 228 g body and 4 g of washers is the stock body: its true mass is the
    body's true mass plus the weighed washers (+-2 %), not a new +-10 % draw."""
    from dyno.sim.tune_deviation import WASHER_REL
    from dyno.tuning.parts import part_identity

    tune = load_tune(STOCK)
    washed = tune.with_changes(**{"flyweights.mass_each_kg": 0.240, "flyweights.washer_mass_each_kg": 0.012})
    drilled = tune.with_changes(**{"flyweights.mass_each_kg": 0.240})  # another body of 240 g
    for world in (5, 6, 7):
        (t0, r0), (t1, r1), (t2, _) = (deviate_tune(t, 0.1, world) for t in (tune, washed, drilled))
        body_true = t0.flyweights.mass_each_kg
        m = t1.flyweights.mass_each_kg
        assert abs(m - (body_true + 0.012)) <= 0.012 * WASHER_REL + 1e-12
        fw = next(r for r in r1 if r["kind"] == "flyweights")
        assert fw["mass_each_kg"]["body_deviation_rel"] == pytest.approx(body_true / 0.228 - 1.0)
        assert abs(t2.flyweights.mass_each_kg - (body_true + 0.012)) > 1e-6  # a new body draws its own
    assert part_identity(tune, "flyweights") == part_identity(washed, "flyweights")
    assert part_identity(tune, "flyweights") != part_identity(drilled, "flyweights")


def test_deviations_are_normal_with_each_fields_own_spread_not_the_advisors_uniform_prior():
    """The advisor's prior is uniform +-tolerance on its six fields; the sim draws each field normal with
    sd = half its own bound (springs' preload +-REL, rate +-0.7 REL, the flyweight body +-0.5 REL, a machined
    helix angle +-0.15 REL): over many rigs the shares differ from a uniform's."""
    t = load_tune(STOCK)
    d = {}
    for w in range(300):
        for r in deviate_tune(t, 0.1, 1000 + w)[1]:
            for f, v in r.items():
                if isinstance(v, dict) and "deviation_rel" in v:
                    d.setdefault((r["kind"], f), []).append(v["deviation_rel"])
    pre = abs(np.array(d[("primary_spring", "preload_n")]))
    assert pre.max() <= 0.1 + 1e-12
    # uniform on +-0.1: half beyond 0.05; normal sd 0.05 cut at 2 sd: ~30 %
    assert 0.2 < np.mean(pre > 0.05) < 0.4
    assert np.std(d[("primary_spring", "rate_n_per_m")]) == pytest.approx(0.035, rel=0.2)
    assert np.std(d[("flyweights", "mass_each_kg")]) == pytest.approx(0.025, rel=0.2)
    assert np.max(np.abs(d[("helix", "angle_from_axis_deg")])) <= 0.015 + 1e-12


def test_engagement_truth_follows_the_true_parts():
    """Engagement at zero load is where the flyweights' force, less the ramps' friction, meets the spring and
    the sheave's bushing at the sim's low stop (Messick eq. 9.3 with the true mass, preload and rate and the
    world's friction), not where the labels (or a frictionless balance) would put it."""
    from dyno.sim.driven import clamp_radius_m
    from dyno.tuning import actuators as act

    # (the flyweights' hidden radius offset of the default rig set to none: this compares with the parts alone)
    label = RigModel(RigParams(cvt_tune_path=STOCK, belt_efficiency_source="loss_model",
                               cvt_flyweight_radius_offset_m=0.0), seed=0)
    dev = _model(0, world_seed=11, cvt_flyweight_radius_offset_m=0.0)
    r_m = clamp_radius_m(dev.params, dev.cvt)
    n0, n1 = label.engagement.rpm_for_capacity(0.0), dev.engagement.rpm_for_capacity(0.0)

    def closing(tune, fr):
        t = tune.with_changes(**{"flyweights.mass_each_kg": tune.flyweights.mass_each_kg * (1 - fr.ramp_friction_frac)})
        return float(act.primary_speed_for_force_rpm(t, 0.5 * fr.sheave_friction_n, r_m))

    assert n1 == pytest.approx(closing(dev.tune_true, dev.cvt.friction), abs=1.0)
    assert n0 == pytest.approx(closing(load_tune(STOCK), label.cvt.friction), abs=1.0)
    assert abs(n1 - n0) > 5.0
    assert n1 > float(act.primary_speed_for_force_rpm(dev.tune_true, 0.0, r_m)) + 5.0  # the friction's share


def test_zero_deviation_is_the_label():
    t = load_tune(STOCK)
    assert deviate_tune(t, 0.0, 3) == (t, ())


def test_cli_flag_and_its_bad_value(tmp_path):
    bad = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--sim-tune-deviation", "0.9",
                          "--out", str(tmp_path / "r")], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--sim-tune-deviation" in bad.stderr
    assert not (tmp_path / "r").exists()
    out = subprocess.run([sys.executable, "-m", "dyno", "run", "--sim", "--headless", "--plan", "engagement",
                          "--json", "--sim-tune-deviation", "0.1", "--sim-world-seed", "11", "--seed", "4",
                          "--out", str(tmp_path / "e")], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    d = json.loads(out.stdout)
    parts = {p["kind"]: p for p in d["sim_world"]["tune_parts"]}
    assert parts == _parts(_model(0, world_seed=11))
    # the measurement sees the true parts: the measured engagement is the deviated rig's truth
    assert abs(d["engagement_rpm"] - d["engagement_rpm_true"]) < 10.0
    label_eng = RigModel(RigParams(cvt_tune_path=STOCK, belt_efficiency_source="loss_model"), seed=0)
    assert abs(d["engagement_rpm_true"] - label_eng.engagement.rpm_for_capacity(0.0)) > 5.0
