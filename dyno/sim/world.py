"""What the simulated rig *is* on a given seed: its own engine, torque sensor and day.

The host knows an engine map, a calibration history and (perhaps) the air.  A rig built from exactly
those could only ever show noise, so the simulated one differs from them the way a real one does,
one draw per seed (every point of a run shares it, as every point of a real run shares its engine):

* **engine**: the shipped map's full-throttle torque times a smooth relative deviation
  :math:`1 + \\delta(n)`, :math:`\\delta` a Gaussian process over engine speed (squared-exponential
  kernel, standard deviation ``engine_map_dev_rel_sd``, correlation length ``engine_map_dev_length_rpm``),
  times ``1 - engine_ageing_loss_frac``, and divided by the day's SAE J1349 factor (the engine breathes
  the day's air: the map is a standard-day map).  The spread is the simulator's own, not what the host
  states its map to: 4.4 %, from a real engine of the class against a representative map (3.9 % RMS:
  the thesis's used-engine chart against the shipped map) and a small engine's day-to-day repeatability
  (~2 %), see :class:`~dyno.sim.rig_params.RigParams`;
* **torque sensor**: gain and offset of the ADC chain drawn about the nominal (the latest entry of the
  thesis rig's calibration history, :class:`~dyno.sim.rig_params.RigParams` ``adc_*``): the slope's
  re-seating and re-calibration scatter (``adc_gain_drift_rel_sd``, 1.5 %), its thermal drift from the
  calibration's temperature to the day's,

  .. math:: g_{true} = g_{nom}\\,(1 + \\epsilon + \\alpha_T (T_{day} - T_{cal}) + s),\\quad
            \\epsilon \\sim N(0, \\sigma_g^2)

  (``adc_gain_tempco_per_k`` :math:`\\alpha_T`, ``adc_calibration_temp_c``; :math:`s` =
  ``world_adc_gain_shift_rel``, 0 but in bench worlds), and the intercepts' scatter
  (``adc_offset_drift_counts_sd``);
* **day**: intake temperature, station pressure and humidity, ``ambient_day`` or drawn (a plausible
  Baja test day: 5…35 °C, 0…1,500 m, 20…80 %RH); the rotor and the thermometer's die sit in it too.

``ideal=True`` is the perfect-knowledge case: the engine exactly its map, the sensor exactly its nominal
calibration, the J1349 reference day (25 °C, 99 kPa dry air) — for tests of statistics alone.

Nothing here reads the host's files or settings: the draws use the simulator's own parameters (which
describe the thesis rig), never the host's ``--engine-map``, ``--calibration`` or ``rig.toml``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from dyno.analysis.air import j1349_factor_of

#: J1349's reference day as a barometer reads it: 25 °C, 99 kPa of dry air, no vapour (CF = 1 exactly).
REFERENCE_DAY = (25.0, 99.0, 0.0)
_DEV_GRID_POINTS = 12  # the deviation's knots across the map's speed range


@dataclass(frozen=True)
class World:
    """One seed's truth (sim-only: the ``sim_world`` record of a run, never an input of the host)."""

    temp_c: float
    pressure_kpa: float
    rh_pct: float
    j1349_factor: float
    engine_dev_rpm: tuple = ()
    engine_dev_rel: tuple = ()
    engine_ageing_loss_frac: float = 0.0
    adc_gain_counts_per_nm: float = math.nan
    adc_offset_counts: float = math.nan
    adc_gain_drift_rel: float = 0.0
    adc_offset_drift_counts: float = 0.0
    ideal: bool = False
    # the engine-side input torque channel (issue 27), drawn from a stream of its own (the draws above do
    # not move when it is fitted); NaN when the rig has none
    input_gain_counts_per_nm: float = math.nan
    input_offset_counts: float = math.nan
    input_gain_drift_rel: float = 0.0
    cradle_bearing_loss_nm: float = 0.0
    # --sim-tune-deviation: each CVT part's label and true value (dyno.sim.tune_deviation); () = as labelled
    tune_parts: tuple = ()

    def engine_dev_rel_at(self, rpm: float) -> float:
        """The engine's relative deviation from its map at ``rpm`` (ageing and air not included)."""
        if not self.engine_dev_rpm:
            return 0.0
        return float(np.interp(rpm, self.engine_dev_rpm, self.engine_dev_rel))

    def true_over_map(self, rpm: float) -> float:
        """True full-throttle torque / the map's, at ``rpm`` on this day (what an efficiency divides by)."""
        return (1.0 + self.engine_dev_rel_at(rpm)) * (1.0 - self.engine_ageing_loss_frac) / self.j1349_factor

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["engine_dev_rpm"], d["engine_dev_rel"] = list(self.engine_dev_rpm), list(self.engine_dev_rel)
        d["tune_parts"] = [dict(x) for x in self.tune_parts]
        return d


def draw_day(rng: np.random.Generator, site_altitude_m: float | None = None) -> tuple[float, float, float]:
    """A plausible test day: 5…35 °C, station pressure at 0…1,500 m (or the site's altitude; ISA) ± 1 kPa of
    weather (sd), 20…80 %RH."""
    temp_c = float(rng.uniform(5.0, 35.0))
    altitude_m = float(rng.uniform(0.0, 1500.0))  # (drawn even at a known site: the later draws stay put)
    altitude_m = altitude_m if site_altitude_m is None else float(site_altitude_m)
    pressure_kpa = 101.325 * (1.0 - 2.25577e-5 * altitude_m) ** 5.25588 + float(rng.normal(0.0, 1.0))
    return temp_c, pressure_kpa, float(rng.uniform(20.0, 80.0))


def draw_deviation(rng: np.random.Generator, rpm_min: float, rpm_max: float, sd_rel: float,
                   length_rpm: float) -> tuple[np.ndarray, np.ndarray]:
    """A smooth relative deviation: a zero-mean Gaussian process on a grid, marginal sd ``sd_rel``.

    .. math:: \\operatorname{cov}(\\delta_i, \\delta_j) = \\sigma^2 \\exp\\left(-\\frac{(n_i - n_j)^2}{2\\ell^2}\\right)
    """
    n = np.linspace(rpm_min, rpm_max, _DEV_GRID_POINTS)
    if sd_rel <= 0.0:
        return n, np.zeros_like(n)
    cov = sd_rel ** 2 * np.exp(-0.5 * ((n[:, None] - n[None, :]) / length_rpm) ** 2)
    chol = np.linalg.cholesky(cov + 1e-12 * np.eye(len(n)))  # jitter: the kernel is near-singular
    return n, chol @ rng.standard_normal(len(n))


def realise(p, seed: int, map_rpm: np.ndarray, map_torque_nm: np.ndarray):
    """This seed's world over the nominal parameters ``p``.

    Returns ``(params, rpm, torque_true_nm, world)``: the parameters with the sensor's true gain and
    offset and the day's temperature, and the true full-throttle torque at the map's speeds.
    The draws use their own random stream, so the rig's noise sequences do not move with them.
    """
    if p.ideal:
        t, pr, rh = p.ambient_day or REFERENCE_DAY
        w = World(t, pr, rh, j1349_factor_of(t, pr, rh), adc_gain_counts_per_nm=p.adc_gain_counts_per_nm,
                  adc_offset_counts=p.adc_offset_counts, ideal=True)
        if p.input_torque_fitted:
            w = dataclasses.replace(w, input_gain_counts_per_nm=p.input_gain_counts_per_nm,
                                    input_offset_counts=p.input_offset_counts)
        q = dataclasses.replace(p, ambient_temp_c=t)
        return q, map_rpm, map_torque_nm / w.j1349_factor, w
    seed = int(seed if p.world_seed is None else p.world_seed)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x24]))  # (0x24: this world's stream)
    day = draw_day(rng, p.site_altitude_m)  # drawn even when given, so the other draws do not depend on it
    t, pr, rh = p.ambient_day or day
    dev_rpm, dev_rel = draw_deviation(rng, float(map_rpm[0]), float(map_rpm[-1]), p.engine_map_dev_rel_sd,
                                      p.engine_map_dev_length_rpm)
    gain_drift = (float(rng.normal(0.0, 1.0)) * p.adc_gain_drift_rel_sd  # re-seating, re-calibration
                  + p.adc_gain_tempco_per_k * (t - p.adc_calibration_temp_c) + p.world_adc_gain_shift_rel)
    offset_drift = float(rng.normal(0.0, 1.0)) * p.adc_offset_drift_counts_sd
    cf = j1349_factor_of(t, pr, rh)
    w = World(t, pr, rh, cf, tuple(float(x) for x in dev_rpm), tuple(float(x) for x in dev_rel),
              p.engine_ageing_loss_frac, p.adc_gain_counts_per_nm * (1.0 + gain_drift),
              p.adc_offset_counts + offset_drift, gain_drift, offset_drift)
    if p.input_torque_fitted:
        w = _with_input(w, p, seed)
    torque = np.array([tq * w.true_over_map(n) for n, tq in zip(map_rpm, map_torque_nm)])
    q = dataclasses.replace(p, adc_gain_counts_per_nm=w.adc_gain_counts_per_nm,
                            adc_offset_counts=w.adc_offset_counts, ambient_temp_c=t)
    return q, map_rpm, torque, w


def _with_input(w: World, p, seed: int) -> World:
    """This seed's input torque channel: gain, offset and the cradle bearings' friction torque."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x27]))  # (0x27: the input channel's stream)
    gain_drift = float(rng.normal(0.0, 1.0)) * p.input_gain_drift_rel_sd
    offset = p.input_offset_counts + float(rng.normal(0.0, 1.0)) * p.input_offset_drift_counts_sd
    bearing = abs(float(rng.normal(0.0, 1.0))) * p.cradle_bearing_loss_sd_nm
    return dataclasses.replace(w, input_gain_counts_per_nm=p.input_gain_counts_per_nm * (1.0 + gain_drift),
                               input_offset_counts=offset, input_gain_drift_rel=gain_drift,
                               cradle_bearing_loss_nm=bearing)


def input_channel_truth(p, seed: int) -> tuple[float, float, float]:
    """This seed's input torque channel as a run's world draws it (:func:`realise`): the cradle load cell's
    true gain (counts per N m of crank torque), offset (counts) and the bearings' friction (N m).

    For the calibration fixture (``dyno calibrate --sim --channel input``) and the tests that judge a
    calibration against the physics; from the simulator's parameters ``p`` alone, never the host's history.
    """
    w = _with_input(World(math.nan, math.nan, math.nan, math.nan), p, int(seed if p.world_seed is None
                                                                           else p.world_seed))
    return w.input_gain_counts_per_nm, w.input_offset_counts, w.cradle_bearing_loss_nm
