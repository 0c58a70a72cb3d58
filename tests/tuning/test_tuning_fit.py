"""Fit to the rig (issue 7 part E) on the simulated rig, validated against a different model.

The simulated CVT (dyno.sim.cvt, belt mode) balances flyweights minus spring
(Messick eq. 9.3) against springs plus helix (Sorge eq. 22) with hidden "true"
values of the three uncertain parameters, but its belt thrust ratio comes from
the capstan tier (Gerbert's V-belt, dyno.model.capstan), NOT from the closed
form (Sorge & Cammalleri eqs. 17-18) that the fit uses: the fit is not
validated against itself.  The measured points come through the whole chain
(sensor noise, firmware protocol, host averaging, settling detection).  The
bounds below are what was measured (seeds 11-13); docs/tuning.md states them.
"""

import json
import math
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from dyno.tuning.fit import PARAMETERS, fit_runs, load_fit_run, solver_for
from dyno.tuning.shift_curve import compare_to_measured, predict_shift_curve
from dyno.tuning.tune import dumps_tune, load_tune

ROOT = Path(__file__).resolve().parents[2]
STOCK = ROOT / "calibration/tunes/cvtech-stock.toml"

#: Hidden truth of the simulated rig (nominal: 0.4, 0 mm, 0 N m).
TRUE = {"belt_friction_coefficient": 0.33, "flyweight_radius_offset_m": 0.0015,
        "secondary_friction_torque_nm": 0.8}

#: Three tunes.  A heavier flyweight alone leaves the force balance at a given
#: ratio and load unchanged (only the rpm moves), so the radius offset (a
#: relative change of the centrifugal force) and the shaft drag (a constant
#: helix force) would stay ~100 % correlated; a stiffer primary spring and a
#: steeper helix change those two forces' proportions and separate them.
#: All share a full-shift primary radius of 79 mm, which puts the tune's high
#: stop at the sim's 0.72 (the stock 93 mm gives 0.42, beyond the rig's range).
TUNE_CHANGES = {
    "fit-stock": {},
    "fit-heavy-stiff": {"flyweights.mass_each_kg": 0.30, "primary_spring.preload_n": 850.0},
    "fit-steep-helix": {"flyweights.mass_each_kg": 0.26, "helix.angle_from_axis_deg": 60.0,
                        "secondary_spring.preload_n": 300.0},
}


def _simulate(name: str, changes: dict, seed: int, root: str) -> str:
    """One complete simulated steady-state test (~10-15 s), its tune saved
    with the run (runs do not store their tune yet; the setup hook does)."""
    from dyno.session.root import RunSpec, run_test
    from dyno.control.api import TestPlan
    from dyno.sim.rig_params import RigParams
    from dyno.tuning.shift_curve import Solver, load_engine_map
    from dyno.tuning.tune import model_params_for

    tune = load_tune(STOCK).with_changes(**{"drive.primary_radius_max_m": 0.079, "name": name, **changes})
    tune_path = Path(root) / f"{name}.toml"
    tune_path.write_text(dumps_tune(tune))
    engine = load_engine_map(ROOT / "calibration/engine_maps/baja-10hp-representative.csv")
    stops = Solver(tune, engine, model_params_for(tune))
    rig = RigParams(cvt_tune_path=str(tune_path), cvt_ratio_low=stops.ratio_low_stop,
                    cvt_ratio_high=stops.ratio_high_stop,
                    cvt_belt_friction_coefficient=TRUE["belt_friction_coefficient"],
                    cvt_flyweight_radius_offset_m=TRUE["flyweight_radius_offset_m"],
                    cvt_secondary_friction_torque_nm=TRUE["secondary_friction_torque_nm"],
                    cvt_belt_thrust_model="capstan")
    out = Path(root) / name

    def save_tune(ctx):
        (Path(ctx.writer.run_dir) / "tune.toml").write_text(dumps_tune(tune))

    # 3 s averages (no efficiency-SEM extension): the fit needs rpm, not efficiency.
    res = run_test(RunSpec(sim=True, seed=seed, out_dir=out, sim_params=rig, setup=save_tune,
                              plan=TestPlan(target_efficiency_sem=1.0)))
    assert res["state"] == "done", res["reason"]
    return str(out)


@pytest.fixture(scope="session")
def run_dirs(tmp_path_factory):
    root = tmp_path_factory.mktemp("fit_runs")
    with ProcessPoolExecutor(max_workers=3) as pool:
        futs = [pool.submit(_simulate, name, ch, 11 + k, str(root)) for k, (name, ch) in enumerate(TUNE_CHANGES.items())]
        return [f.result() for f in futs]


@pytest.fixture(scope="session")
def runs(run_dirs):
    return [load_fit_run(d) for d in run_dirs]


@pytest.fixture(scope="session")
def fit(runs):
    return fit_runs(runs)


def test_runs_cover_the_shift(runs):
    for run in runs:
        assert len(run.points) >= 12
        ratios = [p.engine_rpm / p.secondary_rpm for p in run.points]
        assert min(ratios) < 0.75 and max(ratios) > 1.7  # from the high stop well into the shift (1.75-1.96)


def test_recovered_parameter_error_against_a_different_truth_model(fit):
    """Measured (seeds 11-13, 50 points off the stops, the re-estimated stock tune): f 1.00 (its upper
    bound; true 0.33), dr -14.1 mm (true +1.5), T_fr -7.3 N m (true +0.8).  The closed form's thrust ratio is not the
    capstan truth's (it differs in level and in its ratio/torque shape), and the fit absorbs the
    difference into effective parameter values: they are not the physical ones."""
    p, sig = fit.parameters, fit.sigma
    assert abs(p["belt_friction_coefficient"] - TRUE["belt_friction_coefficient"]) <= 0.7
    assert abs(p["flyweight_radius_offset_m"] - TRUE["flyweight_radius_offset_m"]) <= 20e-3
    assert abs(p["secondary_friction_torque_nm"] - TRUE["secondary_friction_torque_nm"]) <= 10.0
    # the fit's sigma is a noise bar, not a model-error bar: dr's error is many sigma (measured 12)
    err_dr = abs(p["flyweight_radius_offset_m"] - TRUE["flyweight_radius_offset_m"])
    assert err_dr > 3.0 * sig["flyweight_radius_offset_m"]
    assert np.allclose(np.diag(fit.correlation), 1.0)
    assert fit.dof == fit.n_points_fit - 3


def test_model_error_shows_in_the_residuals(fit):
    # measured: rms 189 rpm at nominal -> 54 rpm fitted (max 152): the fitted values buy a better fit
    # with unphysical parameters
    assert fit.after["rms_rpm"] < 0.5 * fit.before["rms_rpm"]
    assert fit.before["rms_rpm"] > 150.0
    # the residual scatter (59 rpm) is model error, ~40x the measurement's (1.5 rpm with a circular truth)
    assert 30.0 < fit.residual_std_rpm < 150.0
    assert fit.after["max_abs_rpm"] <= 300.0


def test_predicted_shift_curve_against_the_measured_points(runs, fit):
    """The engine-map shift curve with the fitted parameters: measured 309-355 rpm worst point per run, all
    at the start of the shift, where the flat engine speed makes the map-load fixed point sensitive to the
    unphysical fitted drag (the 50 rpm target of issue 7 holds only against the circular truth)."""
    for run in runs:
        solver = solver_for(run.tune, run.engine, list(fit.parameters.values()))
        curve = predict_shift_curve(run.tune, run.engine, params=solver.params,
                                    secondary_friction_torque_nm=solver.secondary_friction_torque_nm,
                                    flyweight_radius_offset_m=solver.flyweight_radius_offset_m)
        cmp = compare_to_measured(curve, [{"engine_rpm": p.engine_rpm, "secondary_rpm": p.secondary_rpm}
                                          for p in run.points])
        assert cmp["max_abs_rpm"] <= 400.0, (run.name, cmp)


def test_cli_shift_curve_fit(run_dirs, capsys):
    from dyno.cli import main

    # One run keeps this quick (the three-run fit is the tests above).
    assert main(["shift-curve", str(STOCK), "--fit", run_dirs[1], "--no-sensitivity", "--json",
                 "--points", "10"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data["fit"]["parameters"]) == set(PARAMETERS)
    assert data["fit"]["after"]["rms_rpm"] < data["fit"]["before"]["rms_rpm"]
    assert all(math.isfinite(v) for v in data["fit"]["sigma"].values())


def test_run_without_a_tune_names_the_missing_file(tmp_path, run_dirs):
    import shutil

    from dyno.errors import ConfigError

    bare = tmp_path / "bare"
    shutil.copytree(run_dirs[0], bare)
    (bare / "tune.toml").unlink()
    with pytest.raises(ConfigError, match="tune.toml"):
        load_fit_run(bare)
    assert load_fit_run(bare, tune=STOCK).tune.name == "cvtech-stock"


def test_fit_and_run_comparison_are_one_prediction_on_one_engine_map(run_dirs, capsys):
    """issue 25: `--fit A --run B` compared B with the default (part-throttle) map while the fit used the
    runs' own; now the curve and the comparison use the run's stored map, and the comparison at each
    point's measured load is the fit's own prediction: fitted and compared on one run, the two agree."""
    from dyno.cli import main

    assert main(["shift-curve", str(STOCK), "--fit", run_dirs[1], "--run", run_dirs[1], "--no-sensitivity",
                 "--json", "--points", "10"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert Path(data["engine_map"]) == Path(run_dirs[1]) / "engine_map.csv"
    assert data["comparison"]["at_measured_load"]["rms_rpm"] == pytest.approx(data["fit"]["after"]["rms_rpm"],
                                                                               rel=1e-9)
