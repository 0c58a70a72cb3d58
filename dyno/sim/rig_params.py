"""Every parameter of the simulated rig (:class:`RigParams`, units in the names) and its file defaults.

The parameters with their sources, and the repository-relative defaults
(engine map, CVT tune) with how a path is resolved.  What the numbers of the signal chain were
measured from is in :mod:`dyno.sim.rig_signals`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from dyno.resources import FOLDERS, resource

DEFAULT_ENGINE_MAP = "calibration/engine_maps/baja-10hp-representative.csv"
DEFAULT_TUNE = "calibration/tunes/cvtech-stock.toml"


def load_sim_tune(path: str | None):
    """The CVT tune for the shift balance, or None for the closed form.

    Uses :mod:`dyno.tuning` (another part of the project) when it is
    importable; a missing package falls back to the closed form, a broken
    tune file is an error (ConfigError naming file and field).
    """
    if not path:
        return None
    try:
        from dyno.tuning.tune import load_tune
    except ImportError:
        return None
    return load_tune(resolve_map_path(path))


def resolve_map_path(path: str) -> Path:
    p = Path(path)
    if p.is_absolute():
        return p
    # A shipped file by design (the default: "calibration/..."), so it works from any cwd and from a wheel;
    # fall back to cwd-relative for user-supplied relative paths.
    if p.parts and p.parts[0] in FOLDERS:
        shipped = resource(p.as_posix())
        if shipped.exists() or not p.exists():
            return shipped
    return p


@dataclass
class RigParams:
    """Every parameter of the simulated rig (units in the names).

    Defaults describe the thesis rig (Messick 2018, Sections 8-9) where it
    gives a number, and representative values elsewhere (commented).
    """

    # ---- engine
    engine_map_path: str = DEFAULT_ENGINE_MAP
    engine_inertia_kg_m2: float = 0.045          # crank + flywheel + primary pulley
    engine_idle_rpm: float = 1800.0
    engine_idle_offset_rpm: float = 20.0         # governor set point above idle: friction balance lands on ~1800
    engine_governor_droop_rpm: float = 150.0     # part-throttle governor band
    engine_friction_nm: float = 1.5              # motoring friction at 0 rpm
    engine_friction_at_3600_rpm_nm: float = 3.0  # motoring friction + pumping at 3600 rpm
    engine_firing_ripple_ratio: float = 1.8      # half-order gas-torque amplitude / gross torque
    engine_stall_rpm: float = 600.0
    # The engine is not its map (dyno.sim.world): a smooth deviation drawn per seed with this relative
    # standard deviation and correlation length, an optional ageing loss, and the day's air (J1349).
    # 4.4 %, the simulator's own (not the host's stated map term): a representative map against one real
    # engine of its class differs by 3.9 % RMS (the thesis's digitised chart of a used 10 hp Baja engine
    # against the shipped hand-written map, 1,800-3,400 rpm: unit-to-unit and map shape together), and a
    # small carburetted engine repeats day to day within ~2 % (fuel, plug, warm-up, filter): sqrt(3.9² + 2²).
    engine_map_dev_rel_sd: float = 0.044
    engine_map_dev_length_rpm: float = 700.0
    engine_ageing_loss_frac: float = 0.0
    # The day (intake air): (temp_c, station pressure_kpa, rh_pct), or None = drawn per seed.
    ambient_day: tuple | None = None
    # The site (m): a drawn day's pressure is this altitude's (ISA) with the weather; None = drawn 0…1,500 m.
    # Where the rig stands is a fact of the world (rig.toml [ambient] altitude_m states it), not the host's knowledge.
    site_altitude_m: float | None = None
    # Perfect knowledge: the engine exactly its map, the sensor exactly its nominal calibration, the
    # J1349 reference day (tests of statistics alone; --sim-ideal).
    ideal: bool = False
    # The world's draws (engine, sensor, day) come from this seed; None = the run's seed.  Two runs with
    # one world_seed and different seeds are the same rig on the same day, measured twice (its noise new).
    world_seed: int | None = None
    engine_start_rpm: float = 1000.0             # speed the pull start leaves the engine at
    # ---- CVT (ratio = primary speed / secondary speed)
    # The stops (each inside what the tune's geometry allows, 3.06..0.42 for the stock drive).  Low: the
    # geometry's (3.1 asks for more than it has): the 2019 logs reached a speed ratio of 2.36 at full load
    # (n_p 2747 / n_s 1166) still shifting, and the engagement speed is the flyweights' at the geometric low
    # stop (~2,360 rpm; a stop at 2.4 put it under the idle).  High: from the logs: run3's five light-load
    # points sit at a speed ratio of 0.547-0.548 (a stop: the load changes, the ratio does not), ~1 % of
    # creep above a geometric 0.54; the real sheaves stop short of the drawing's 93 mm.
    cvt_ratio_low: float = 3.1
    cvt_ratio_high: float = 0.54
    cvt_primary_radius_max_m: float = 0.093      # belt radius at full shift (thesis 9.4.1)
    cvt_sheave_half_angle_deg: float = 13.0
    cvt_flyweight_coeff_kg_m: float = 0.0108     # n m r dr/dz of the flyweights (eq. 9.2), held constant
    cvt_primary_spring_full_shift_n: float = 950.0   # thesis 9.4.1 (spring datasheet)
    cvt_primary_spring_rate_n_per_m: float = 18200.0
    cvt_secondary_spring_preload_n: float = 200.0
    cvt_secondary_spring_rate_n_per_m: float = 5000.0
    cvt_helix_gain_n_per_nm: float = 20.0        # axial force per N*m through the helix
    cvt_shift_time_constant_s: float = 0.4
    # CVT tune for the flyweight/helix forces (dyno.tuning.actuators); "" or
    # None = the closed-form balance above (cvt_flyweight_coeff..helix_gain).
    cvt_tune_path: str | None = DEFAULT_TUNE
    # Each CVT part's true value differs from its label by up to this fraction (normal, each field with its
    # own share of it from its manufacturing norm, dyno.sim.tune_deviation), drawn per part and world seed
    # (--sim-tune-deviation); 0 = every part exactly its label.
    tune_deviation_rel: float = 0.0
    # Engagement (dyno.sim.driven): "clamp" = the primary's slip torque from the net flyweight
    # clamp (the tune's flyweights against its spring preload); "smoothstep" = a fixed
    # ramp of capacity from cvt_engage_start_rpm to cvt_engage_full_rpm, whatever the tune.
    cvt_engagement_model: str = "clamp"
    # The CVT's friction (dyno.sim.cvt_friction): None = drawn per world within its real range (the clutch's
    # belt flank mu 0.30-0.45, the ramps' 0.5-1.5 % and the helix's 1-3 % of their axial force, 2-8 N of
    # sheave bushings); a number = that value (0 = no such friction).
    cvt_clutch_friction_coefficient: float | None = None
    cvt_ramp_friction_frac: float | None = None
    cvt_helix_friction_frac: float | None = None
    cvt_sheave_friction_n: float | None = None
    cvt_engage_start_rpm: float = 1900.0
    cvt_engage_full_rpm: float = 2100.0
    cvt_clutch_capacity_nm: float = 60.0
    cvt_slip_base_frac: float = 0.01
    cvt_slip_per_20nm_frac: float = 0.015
    cvt_loss_frac_min: float = 0.04
    cvt_loss_frac_high_ratio: float = 0.07       # extra loss toward overdrive (thesis Fig. 9.6)
    cvt_loss_frac_low_ratio: float = 0.02
    cvt_ratio_best_eff: float = 1.35
    cvt_bending_drag_nm: float = 0.25
    # Belt efficiency: "loss_model" = the simple loss model above; "belt_model" =
    # the full belt model's share (dyno.sim.belt_table, built once per machine in
    # the overlay cache) + the loss model's parasitic remainder (see dyno.sim.cvt).
    belt_efficiency_source: str = "belt_model"
    belt_table_cache_dir: str | None = None      # None = $DYNO_MODEL_CACHE or ~/.cache/dyno/model
    # The belt's thrust ratio F_s,belt / F_p (dyno.sim.belt_thrust): by default the full belt model's, from
    # the belt table's cells; a number = the capstan tier (or the closed form, below) at this belt-sheave
    # friction coefficient instead (--sim-belt-thrust F).
    cvt_belt_friction_coefficient: float | None = None
    # Added to the tune's flyweight radius table: the real weights' centre of mass, which no drawing gives.
    # -3 mm: a fit (least RMS engine speed against speed ratio) to the 2019 logs' run2, checked on run3 and run4
    # (bench/bench_fidelity.py; docs/measurements/2026-11-29-fidelity-driveline.md).
    cvt_flyweight_radius_offset_m: float = -0.003
    # Which belt tier gives the true thrust ratio: "full" (the full model's cells; with a friction given,
    # the capstan tier), "capstan" (Gerbert's V-belt limit, dyno.model.capstan) or "closed_form" (the
    # model dyno.tuning.fit fits: circular, for comparison only).
    cvt_belt_thrust_model: str = "full"
    # Bearing/seal drag on the secondary shaft after the helix: the helix feels
    # the belt torque, the torque gauge (and the brake) that minus this.
    cvt_secondary_friction_torque_nm: float = 0.0
    # Driven-side parasitic loss a + b w + c w^2 (N m, w in rad/s of the secondary), upstream of
    # the torque gauge (dyno.sim.driven); off by default, see there.
    driven_loss_nm: tuple = (0.0, 0.0, 0.0)
    # ---- driveline between the CVT and the torque gauge (dyno.sim.physics, "Driveline loss"): the secondary
    # shaft's two ball bearings and seal, and the chain (or gear pair) to the brake shaft.  At the secondary:
    #   T_dl = drag + drag_per_krpm * n_s / 1000 + load_frac * T_s
    # Basis: a lubricated roller chain transmits 98-99 % of its load (ANSI B29 / chain makers' design
    # guides: 1-2 % mesh loss, proportional to the load): 1 %; deep-groove bearings and a lip seal on a ~25 mm
    # shaft drag 0.05-0.1 N·m each lightly loaded (bearing makers' friction models: a speed-dependent viscous
    # part and a load-independent seal part), the chain's slack-side churn adds a little: 0.12 N·m + 0.01 N·m
    # per 1000 rpm from the makers' figures.  The 2019 logs hold the drag to half that: run3's CVT sat on its
    # overdrive stop up to 6.4 N·m at the gauge, and more light-load drag pulls the simulated CVT off the stop
    # sooner (the CVT's friction ranges and flyweight offset were fitted to those logs without a driveline, so
    # part of the real one is already in them; docs/measurements/2026-11-29-fidelity-driveline.md): 0.06 N·m +
    # 0.005 N·m per 1000 rpm, the chain's 1 % kept.  So 2-3 % at light load and high speed, ~1.2 % at full
    # load.  Fixed (one rig's driveline, not drawn per seed).  None = that default (DEFAULT_DRIVELINE_LOSS), or none with ``ideal``
    # (perfect knowledge: the host assumes no driveline); a number is used as given, ideal or not.
    # The belt's efficiency (Truth.efficiency, efficiency_true) is the CVT's alone; the gauge sees the
    # belt's output less this (Truth.driveline_loss_nm, driveline_loss_true_nm).
    driveline_loss_drag_nm: float | None = None
    driveline_loss_drag_nm_per_krpm: float | None = None
    driveline_loss_load_frac: float | None = None
    # ---- driveline inertias
    secondary_inertia_kg_m2: float = 0.013       # secondary pulley + shaft + 32 t gear
    brake_shaft_inertia_kg_m2: float = 0.044     # 61 t gear + brake shaft + rotor
    gear_ratio_brake_per_secondary: float = 32.0 / 61.0
    # ---- brake
    actuator_speed_mm_s: float = 5.0
    actuator_travel_mm: float = 40.0             # 8 s full stroke at 5 mm/s (the host's release time)
    # Direction relay (DPDT, rest = release): from the coil's change until the contacts make on the
    # other side (operate ~10 ms + bounce ~5 ms, automotive relay data sheets). The motor is
    # unpowered meanwhile. The driver's rig.toml relay_settle_s (30 ms) must cover it.
    relay_transfer_s: float = 0.015
    brake_free_travel_mm: float = 1.0
    # where the actuator starts (--sim-brake-start): a rig switched on with the brake applied; the host is not told
    brake_start_mm: float = 0.0
    brake_spring_rate_n_per_mm: float = 6.5      # ~22 steps of 0.2 s from light load to n_s < 1500 rpm
    master_cylinder_bore_mm: float = 19.05
    caliper_piston_bore_mm: float = 48.0
    brake_pad_radius_m: float = 0.10
    brake_mu_cold: float = 0.40
    brake_mu_fade_per_c: float = 6e-4
    brake_mu_floor_frac: float = 0.5
    brake_residual_drag_nm: float = 0.5          # at the brake shaft, pads just touching
    rotor_heat_capacity_j_per_k: float = 2800.0  # ~6 kg cast-iron rotor
    rotor_cooling_w_per_k: float = 8.0
    rotor_cooling_w_per_k_per_rad_s: float = 0.15
    ambient_temp_c: float = 25.0                 # (the day's, set by dyno.sim.world)
    rotor_temp_limit_c: float = 600.0            # physical sanity cap only; the controller's limit is its own
    # ---- torque sensor chain
    adc_gain_counts_per_nm: float = 108.188097293   # counts per N*m of SECONDARY torque (thesis eq. 9.1)
    adc_offset_counts: float = 35144.7019735
    # The sensor drifts from its calibration (dyno.sim.world), the simulator's own model of it: the shaft
    # re-seated and re-calibrated scatters its slope by 1.5 % relative sd (the thesis rig's four calibrations,
    # the only record, scatter 1.57 %: a sample of four, so 0.9-5.9 % at 95 %; rounded to the record), and
    # the bridge's sensitivity follows the day's temperature: the steel shaft's shear modulus falls ~0.025 %
    # per K (so more strain per N m), gauge factor drift being an order smaller, from a calibration made at
    # adc_calibration_temp_c.  Intercepts scatter 63 counts sd (0.58 N m, the record's); the host's zero at
    # rest before GO measures the offset.
    adc_gain_drift_rel_sd: float = 0.015
    adc_gain_tempco_per_k: float = 2.5e-4
    adc_calibration_temp_c: float = 20.0
    adc_offset_drift_counts_sd: float = 63.0
    # ---- bench worlds (bench/bench_uncertainty.py): errors no host assumes, off by default.  A shift of
    # the sensor's true slope from its calibration shared by every world (a calibration moved, e.g. a lever
    # arm mis-measured), and a fraction of the CVT's output torque lost between the CVT and the gauge
    # (chain, bearings) on top of any modelled drag (``driven_loss_nm``).
    world_adc_gain_shift_rel: float = 0.0
    world_driveline_loss_frac: float = 0.0
    # The gauge's slope drifting *within* a run as the brake warms the shaft beside it: relative change per K
    # of the rotor above the day (0 by default; bench_uncertainty's gauge-drift world).  A drift the host's
    # calibration term (one slope scatter per run, independent of the load history) does not describe: it
    # grows over the run, so the points share it unequally (the later, hotter ones more).
    adc_gain_rotor_tempco_per_k: float = 0.0
    # The air sensor reading warm (or cold) by this much (°C) on top of its own data-sheet error: a
    # sensor beside a warm engine bay or board (0 by default; bench_uncertainty's air-sensor world).  The host
    # states a rectangular ±1 °C about the reading, not a bias.
    bme280_temp_bias_c: float = 0.0
    adc_zero_drift_nm_per_min: float = 0.0       # linear zero drift, secondary N m per minute (dyno.sim.driven)
    lockin_cutoff_hz: float = 15.0
    lockin_filter_order: int = 2
    adc_rate_hz: float = 125.0
    adc_clock_error_frac: float = 0.015
    adc_noise_counts: float = 85.0
    adc_noise_counts_per_nm: float = 5.0
    # Shaft-torque ripple amplitudes BEFORE the lock-in filter, as fractions
    # of the mean brake-shaft torque (measured through a 2nd-order filter;
    # see dyno.sim.rig_signals).  Firing order: tabulated against secondary
    # torque (N*m, fraction), linear in between, clamped at the ends.
    ripple_firing_frac_table: tuple = ((0.0, 0.7), (4.0, 0.8), (6.5, 1.0), (9.0, 1.2), (21.0, 1.2),
                                       (25.0, 0.8), (29.0, 0.5), (35.0, 0.42))
    ripple_engine_rev_frac: float = 0.22
    ripple_brake_shaft_frac: float = 0.08
    adc_error_prob: float = 0.0
    # ---- engine-side input torque channel (issue 27, dyno.sim.input_torque): a load cell on the engine
    # cradle's reaction arm, read by a second AD7171.  Fitted when rig.toml declares [input_torque].
    input_torque_fitted: bool = False
    input_gain_counts_per_nm: float = 600.0      # counts per N m of crank torque (nominal; 0.2 m arm, 2 mV/V cell)
    input_offset_counts: float = 33500.0
    # drawn per seed (dyno.sim.world) with the reproducibility of a calibration history like the
    # brake-side channel's (its four slopes: 1.57 %), and an offset scatter
    input_gain_drift_rel_sd: float = 0.016
    input_offset_drift_counts_sd: float = 60.0
    input_noise_counts: float = 60.0             # bridge + amplifier white noise per conversion
    input_noise_counts_per_nm: float = 4.0       # more under load (engine vibration on the cradle)
    input_zero_drift_nm_per_min: float = 0.0
    input_rate_hz: float = 125.0
    input_clock_error_frac: float = 0.012        # its own RC clock, not the first converter's
    input_cutoff_hz: float = 5.0                 # its anti-alias filter (2nd order): the means are what is read
    cradle_bearing_loss_sd_nm: float = 0.08      # trunnion bearing friction held off the load cell, |N(0, sd)|
    input_error_prob: float = 0.0
    # ---- rotor thermometer (MLX90614): first-order optical/filter lag and read noise;
    # quantisation (0.02 K) comes from its word format in dyno.sim.bus
    thermometer_time_constant_s: float = 0.15
    thermometer_noise_c: float = 0.05
    # ---- Hall sensors
    hall_bounce_prob: float = 0.05
    hall_bounce_min_s: float = 50e-6
    hall_bounce_max_s: float = 500e-6
    hall_primary_phase_rad: float = 0.7          # magnet position relative to the firing cycle
    # ---- numerics
    max_substep_s: float = 0.004                 # fixed physics cell; also the input latency bound


#: (drag N·m, drag N·m per 1000 rpm, load fraction): the default rig's driveline (see RigParams)
DEFAULT_DRIVELINE_LOSS = (0.06, 0.005, 0.01)


def driveline_loss_of(p: RigParams) -> tuple[float, float, float]:
    """The rig's driveline loss coefficients (drag N·m, N·m per 1000 rpm, load fraction): each given one as
    given, the others the default's, or zero with ``ideal``."""
    given = (p.driveline_loss_drag_nm, p.driveline_loss_drag_nm_per_krpm, p.driveline_loss_load_frac)
    return tuple(float(g) if g is not None else (0.0 if p.ideal else d) for g, d in zip(given, DEFAULT_DRIVELINE_LOSS))


def _belt_table_for(p: RigParams, tune=None):
    """The belt-model efficiency table (at ``tune``'s clamp) when ``belt_efficiency_source == "belt_model"``."""
    if p.belt_efficiency_source == "loss_model":
        return None
    if p.belt_efficiency_source != "belt_model":
        raise ValueError(f"belt_efficiency_source: 'belt_model' or 'loss_model', got {p.belt_efficiency_source!r}")
    from dyno.sim.belt_table import belt_table

    return belt_table(p.belt_table_cache_dir, tune)


def belt_tables_for(p: RigParams, tune=None) -> dict:
    """The CVT's tables: ``belt_table`` (efficiency, :func:`_belt_table_for`) and ``thrust_table`` (the full
    model's thrust ratio, :mod:`dyno.sim.belt_thrust`).  The thrust ratio is a property of the belt on its drive
    at a load relative to the clamp, so a tune without its own table (``belt_efficiency_source = "loss_model"``,
    a tune the advisor proposes) reads the stock tune's where the drive is the same (the conftest and the first
    run build it once per machine), else its own."""
    eff = _belt_table_for(p, tune)
    thrust = eff
    if (thrust is None and tune is not None and p.cvt_belt_thrust_model == "full"
            and p.cvt_belt_friction_coefficient is None):
        from dyno.sim.belt_table import belt_table

        stock = load_sim_tune(DEFAULT_TUNE)
        same_drive = stock is not None and stock.to_dict().get("drive") == tune.to_dict().get("drive")
        thrust = belt_table(p.belt_table_cache_dir, stock if same_drive else tune)
    return {"belt_table": eff, "thrust_table": thrust}
