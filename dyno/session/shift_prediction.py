"""The tune's predicted shift, as the characterisation plan reads it (:class:`dyno.control.api.ShiftPrediction`).

Built by the root from the tune on the rig and the engine map's file, so the plan reads no file and
imports nothing of :mod:`dyno.tuning`.  The solver (:class:`dyno.tuning.shift_curve.Solver`) is built
at the first question: a run that never asks pays nothing.

The shift-out at a light measured load ``T_s``: the flyweights' axial force balances the secondary's
clamp at the tune's low stop, ``F_p(n) = F_s(T_s, r_s,closed)``, solved for the engine speed ``n`` at the
primary's smallest radius (:mod:`dyno.tuning.actuators`), the belt passing the clamp unchanged.
"""

from __future__ import annotations

import math


class TuneShiftPrediction:
    """The prediction of ``tune`` (a :class:`dyno.tuning.tune.Tune`) with the engine map read from ``map_source``."""

    def __init__(self, tune, map_source) -> None:
        self.tune = tune
        self._map_source = map_source
        self._solver = None

    @property
    def tune_name(self) -> str:
        return self.tune.name

    def _solved(self):
        if self._solver is None:
            from dyno.tuning.shift_curve import Solver, load_engine_map
            from dyno.tuning.tune import model_params_for

            self._solver = Solver(self.tune, load_engine_map(self._map_source), model_params_for(self.tune))
        return self._solver

    @property
    def ratio_low_stop(self) -> float:
        return self._solved().ratio_low_stop

    @property
    def ratio_high_stop(self) -> float:
        return self._solved().ratio_high_stop

    def engagement_rpm(self) -> float:
        return self._solved().engagement_rpm()

    def shift_out_rpm_full_load(self) -> float:
        s = self._solved()
        return s.balance_rpm(s.ratio_low_stop)

    def shift_out_at_load_rpm(self, torque_secondary_nm: float) -> float:
        from dyno.tuning import actuators as act

        if not math.isfinite(torque_secondary_nm):
            return math.nan
        tune = self.tune
        f_s = act.secondary_axial_force_n(tune, max(0.0, torque_secondary_nm), act.secondary_radius_closed_m(tune))
        return float(act.primary_speed_for_force_rpm(tune, f_s, tune.drive.primary_radius_min_m))


def shift_prediction_for(tune, engine_map) -> TuneShiftPrediction | None:
    """The prediction of ``tune`` with ``engine_map``'s file (a map taken to the day names it in
    ``file_source``); None without a tune or a map file."""
    src = getattr(engine_map, "file_source", None) or getattr(engine_map, "source", None)
    if tune is None or not src:
        return None
    return TuneShiftPrediction(tune, src)
