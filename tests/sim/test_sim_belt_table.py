"""Belt-model efficiency table of the simulated CVT (dyno.sim.belt_table)."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from dyno.errors import DidNotConverge
from dyno.sim.belt_table import DEFAULT_RATIOS, DEFAULT_TORQUES_NM, TABLE_RPM, build_belt_table, tune_clamp_n
from dyno.sim.physics import RigModel
from dyno.sim.rig_params import RigParams

RATIOS = (0.9, 1.0, 1.1)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """3 ratios x 1 torque of the real full model, solved into a fresh cache (~5 s)."""
    cache = tmp_path_factory.mktemp("belt_cache")
    return build_belt_table(RATIOS, (18.0,), cache_dir=cache), cache


def _loss_model_cvt():
    return RigModel(RigParams(belt_efficiency_source="loss_model")).cvt


def test_tiny_table_is_physical_and_monotone(tiny):
    tab, _ = tiny
    assert tab.ok.all() and not tab.errors and tab.solved == 3
    assert np.all((tab.eta_torque > 0.0) & (tab.eta_torque <= 1.0))
    assert np.all((tab.eta_speed > 0.0) & (tab.eta_speed <= 1.0))
    # the belt model's own efficiency is high (~96-99 %), above the rig's measured 80-92 %
    assert np.all(tab.eta_torque * tab.eta_speed > 0.95)
    # creep grows toward low gear (smaller primary wrap); torque efficiency rises toward 1:1+
    assert np.all(np.diff(tab.eta_speed[:, 0]) < 0.0)
    assert np.all(np.diff(tab.eta_torque[:, 0]) > 0.0)


def test_second_build_reads_the_overlay_cache(tiny):
    tab, cache = tiny
    again = build_belt_table(RATIOS, (18.0,), cache_dir=cache)
    assert again.solved == 0  # every cell read, none solved
    np.testing.assert_array_equal(again.eta_torque, tab.eta_torque)
    # the entries are the overlay's: predict_overlay answers from them without solving
    from dyno.model.overlay import predict_overlay

    res = predict_overlay([(1.0, TABLE_RPM, 18.0)], tier="full", cache_dir=cache)
    assert res[0]["cached"] and res[0]["efficiency"]["torque"] == pytest.approx(tab.eta_torque[1, 0])


def test_interpolation_inside_the_range_and_clamped_outside(tiny):
    tab, _ = tiny
    for k, r in enumerate(RATIOS):
        et, es = tab.lookup(r, 18.0)
        assert et == pytest.approx(tab.eta_torque[k, 0], abs=1e-9)
        assert es == pytest.approx(tab.eta_speed[k, 0], abs=1e-9)
    et, es = tab.lookup(0.95, 18.0)
    assert min(tab.eta_torque[:2, 0]) <= et <= max(tab.eta_torque[:2, 0])
    assert min(tab.eta_speed[:2, 0]) <= es <= max(tab.eta_speed[:2, 0])
    assert tab.lookup(0.5, 30.0) == pytest.approx(tab.lookup(0.9, 18.0))   # no extrapolation
    assert tab.lookup(3.0, 5.0) == pytest.approx(tab.lookup(1.1, 18.0))


def test_belt_share_is_part_of_the_total_loss(tiny):
    tab, _ = tiny
    cvt = _loss_model_cvt()
    cvt.belt_table = tab
    for r in (0.9, 0.95, 1.0, 1.05, 1.1):
        for t in (5.0, 12.0, 18.0, 25.0):
            eps_b, s_b = cvt.belt_share(r, t)
            eps, s = cvt.losses(r, t)
            assert 0.0 < eps_b <= eps < 1.0 and 0.0 < s_b <= s < 1.0
            # overall efficiency stays in the thesis's measured range at working loads
            if t >= 12.0:
                assert 0.78 <= cvt.efficiency(t, r) <= 0.93
    # at the reference torque the total equals the simple loss model (remainder = difference)
    ref = _loss_model_cvt()
    assert cvt.efficiency(18.0, 1.0) == pytest.approx(ref.efficiency(18.0, 1.0), abs=1e-12)


def _fake_solver(fail=()):
    """Smooth, physical stand-in for solve_point; raises DidNotConverge at ``fail`` (ratio, torque)."""
    calls = []

    def solve(op, guess):
        calls.append((op.ratio, op.primary_torque_nm, guess is not None))
        if (op.ratio, op.primary_torque_nm) in fail:
            raise DidNotConverge(f"fake: no solution at ratio {op.ratio}")
        creep = 0.004 * op.ratio * op.primary_torque_nm / 10.0
        eff = {"torque": 0.97 + 0.005 * op.ratio, "speed": 1.0 - creep}
        eff["overall"] = eff["torque"] * eff["speed"]
        return SimpleNamespace(summary={"efficiency": eff})

    return solve, calls


def test_continuation_order_and_warm_starts(tmp_path):
    solve, calls = _fake_solver()
    tab = build_belt_table((0.8, 1.0, 1.3, 1.6), (8.0, 18.0), cache_dir=tmp_path, solve=solve)
    assert tab.ok.all() and tab.solved == 8
    assert calls[0] == (1.0, 18.0, False)            # cold only at the Table 6.1 point
    assert all(warm for _, _, warm in calls[1:])     # every other point warm-started
    # creep grows with load
    assert np.all(tab.eta_speed[:, 0] > tab.eta_speed[:, 1])
    et8, _ = tab.lookup(1.15, 8.0)
    et13, es13 = tab.lookup(1.15, 13.0)
    assert et13 == pytest.approx(et8)                # fake torque efficiency is load-independent
    assert tab.lookup(1.15, 8.0)[1] > es13 > tab.lookup(1.15, 18.0)[1]


def test_failed_cells_fall_back_to_the_loss_model(tmp_path, caplog):
    solve, _ = _fake_solver(fail={(1.6, 18.0), (1.6, 8.0)})
    with caplog.at_level(logging.INFO, logger="dyno.sim.belt_table"):  # logged, not printed on every run
        tab = build_belt_table((0.8, 1.0, 1.3, 1.6), (8.0, 18.0), cache_dir=tmp_path, solve=solve)
    assert not tab.ok[3].any() and tab.ok[:3].all()
    assert set(tab.errors) == {(1.6, 18.0), (1.6, 8.0)}
    assert "did not converge" in caplog.text and "loss model" in caplog.text
    assert tab.lookup(1.6, 18.0) is None and tab.lookup(1.5, 12.0) is None
    assert tab.lookup(1.0, 12.0) is not None
    cvt = _loss_model_cvt()
    ref = cvt.losses(1.6, 18.0)
    cvt.belt_table = tab
    assert cvt.losses(1.6, 18.0) == ref               # loss model in the failed cell
    assert cvt.belt_share(1.6, 18.0) is None
    assert cvt.losses(1.0, 12.0) != _loss_model_cvt().losses(1.0, 12.0)
    # the failure is cached like the overlay caches it: not re-solved next time
    solve2, calls2 = _fake_solver()
    again = build_belt_table((0.8, 1.0, 1.3, 1.6), (8.0, 18.0), cache_dir=tmp_path, solve=solve2)
    assert calls2 == [] and not again.ok[3].any()


def test_belt_efficiency_source_is_validated():
    with pytest.raises(ValueError, match="belt_efficiency_source"):
        RigModel(RigParams(belt_efficiency_source="magic"))
    assert RigModel(RigParams(belt_efficiency_source="loss_model")).cvt.belt_table is None


def test_default_table_covers_the_sim_range_at_the_tunes_clamp(tmp_path):
    """The default grid spans the simulated CVT's whole ratio range, each cell at the tune's clamp."""
    from dyno.model.inverse import clamp_from_tune
    from dyno.sim.rig_params import DEFAULT_TUNE, load_sim_tune

    tune = load_sim_tune(DEFAULT_TUNE)
    cvt = RigModel(RigParams(belt_efficiency_source="loss_model")).cvt
    assert min(DEFAULT_RATIOS) <= cvt.ratio_high and max(DEFAULT_RATIOS) >= cvt.ratio_low
    seen = []

    def solve(op, guess):
        seen.append(op)
        return _fake_solver()[0](op, guess)

    tab = build_belt_table(cache_dir=tmp_path, tune=tune, solve=solve)
    assert tab.ok.all() and len(seen) == len(DEFAULT_RATIOS) * len(DEFAULT_TORQUES_NM)
    for op in seen:
        assert op.slack_tension_n is None and op.primary_speed_rpm == TABLE_RPM
        assert op.primary_axial_force_n == pytest.approx(tune_clamp_n(tune, TABLE_RPM, op.ratio))
        assert op.primary_axial_force_n == pytest.approx(clamp_from_tune(tune, TABLE_RPM)(op.ratio))
    # flyweights minus spring (stock tune, 3150 rpm): ~1,180 N at the overdrive stop, ~1,520 N round 2, and at the
    # geometric low stop, the flyweights in at their smallest radius, ~460 N
    assert 1100 < tab.clamp_n[0] < 1250 and 1450 < max(tab.clamp_n) < 1600 and 400 < tab.clamp_n[-1] < 520
    assert tab.lookup(2.3, 12.0) is not None      # no clamping to 1.75 any more
    assert tab.lookup(2.3, 12.0) != tab.lookup(1.75, 12.0)


def test_a_complete_cache_is_read_without_waiting_for_the_build_lock(tmp_path):
    """A process building some table holds the lock; one whose table is all cached must not wait for it
    (the tmux tests' blank screens: a reader blocked behind another process's 60 s build)."""
    import fcntl
    import threading

    from dyno.sim import belt_table as bt

    build_belt_table(cache_dir=tmp_path, solve=_fake_solver()[0])  # the default grid, all cells cached
    holder = open(tmp_path / "belt_table.lock", "w")
    fcntl.flock(holder, fcntl.LOCK_EX)  # "another process is building"
    got = []
    try:
        bt._TABLES.pop((str(tmp_path), None), None)
        reader = threading.Thread(target=lambda: got.append(bt.belt_table(cache_dir=tmp_path)), daemon=True)
        reader.start()
        reader.join(20.0)
        assert got, "the reader waited for the build lock although every cell was cached"
        assert got[0].ok.all() and got[0].solved == 0
    finally:
        holder.close()
        bt._TABLES.pop((str(tmp_path), None), None)


def test_a_table_to_solve_is_announced_once_a_cached_one_not(tmp_path, monkeypatch):
    """`dyno run` says on stderr that the sim is solving its table (a first run of a tune took 80 s in silence)."""
    from dyno.sim import belt_table as bt

    said = []
    announcing = bt.announcing_builds(said.append)
    announcing.__enter__()
    real_build = bt.build_belt_table
    monkeypatch.setattr(bt, "build_belt_table",
                        lambda cache_dir=None, tune=None, solve=None: real_build(
                            cache_dir=cache_dir, tune=tune, solve=solve or _fake_solver()[0]))
    try:
        bt.belt_table(cache_dir=tmp_path)  # nothing cached: solved, and said first
        assert said == [None]
        bt._TABLES.pop((str(tmp_path), None), None)
        bt.belt_table(cache_dir=tmp_path)  # all cached now (another process): read, nothing said
        assert said == [None]
    finally:
        announcing.__exit__(None, None, None)
        bt._TABLES.pop((str(tmp_path), None), None)
