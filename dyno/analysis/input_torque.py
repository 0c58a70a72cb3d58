r"""Map-free efficiency from the engine-side input torque channel (issue 27; docs/analysis.md).

With a torque sensor on the engine side (a load cell on the engine cradle's reaction arm, or an in-line
rotary sensor) a point's input power is measured, not taken from the engine map:

.. math:: \eta = \frac{T_s\,\omega_s}{T_{in}\,\omega_p}, \qquad T_{in} = \frac{\bar c - b'}{a} + T_{bearing}

where :math:`\bar c` is the window's mean code of the second converter, :math:`a` its calibration's slope,
:math:`b'` its intercept taken from the zero read at rest before GO (the tare, as the brake-side channel's),
and :math:`T_{bearing}` what the cradle's trunnion bearings hold off the load cell (rig.toml
``[input_torque] bearing_loss_nm``, with its standard uncertainty ``bearing_loss_u_nm``).

Its systematic part has no engine map and no air in it (the engine's real torque on the day is what is
measured); what remains is each channel's calibration and the cradle's correction:

.. math:: U_{95} = \sqrt{CI_{95}^2 + (2\eta)^2\,(u_{cal,out}^2 + u_{cal,in}^2 + u_{cradle}^2)}

with :math:`u_{cal,in}` the input history's slope reproducibility (and its tare's uncertainty relative to
:math:`T_{in}`), :math:`u_{cradle} = u(T_{bearing}) / T_{in}`.  The map-based figure stays beside it
(``efficiency_engine_map``, ``efficiency_engine_map_u95``), and ``efficiency_source`` says which is which.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from dyno.analysis.efficiency import batch_mean
from dyno.analysis.points import batch_count
from dyno.protocol import v1

ADC_RAILS = (0, 0xFFFF)


@dataclass(frozen=True)
class InputChannel:
    """What the host knows of the input channel: its calibration and the cradle's correction."""

    calibration: object          # CalibrationEntry: counts per N m of crank torque (tared when a zero was read)
    calibration_rel: float       # relative standard uncertainty of its slope (history spread, fit)
    bearing_loss_nm: float = 0.0
    bearing_loss_u_nm: float = 0.1
    tare: dict | None = None     # the zero at rest before GO (dyno.analysis.zero_check.tare's record)
    source: str = ""

    def with_zero(self, zero: dict) -> "InputChannel":
        """The channel measured from ``zero`` (a :func:`~dyno.analysis.zero_check.zero_reading` of it)."""
        from dyno.analysis.zero_check import tare

        cal, rec = tare(self.calibration, zero)
        return dataclasses.replace(self, calibration=cal, tare=rec) if rec is not None else self


def _t975(dof: int) -> float:
    from scipy.stats import t

    return float(t.ppf(0.975, max(1, dof)))


def input_zero(streams, t0_us: int, t1_us: int, channel: InputChannel) -> dict:
    """The input channel's zero at rest over the window the brake-side zero was read in."""
    from dyno.analysis.zero_check import zero_reading

    _, codes, status = streams.input_window(t0_us, t1_us)
    return zero_reading(codes, status, channel.calibration)


def input_zero_check(streams, zero_check: dict, channel: InputChannel) -> dict:
    """The input channel's zero at rest over the brake-side zero checks' windows (before GO, after the
    last point) and its drift, judged against the same ``drift_max_nm`` (here crank N m)."""
    from dyno.analysis.zero_check import drift_check

    def read(z: dict) -> dict:
        if "t_start_us" not in z:
            return {"torque_nm": math.nan, "ci95_nm": math.nan, "why": z.get("why", "not read")}
        return input_zero(streams, z["t_start_us"], z["t_end_us"], channel)

    return drift_check(read(zero_check.get("before") or {}), read(zero_check.get("after") or {}),
                       zero_check.get("drift_max_nm", 0.15))


def input_point(streams, point: dict, channel: InputChannel) -> dict:
    """The input-torque keys of ``point`` (reduced by :func:`~dyno.analysis.points.reduce_point` over
    ``[t_start_us, t_end_us]``): measured input power and efficiency; the map's figure kept beside.

    Returns the keys to update the point with (``efficiency_source`` = ``"input_torque"`` always).
    """
    t0, t1 = int(point["t_start_us"]), int(point["t_end_us"])
    _, codes, status = streams.input_window(t0, t1)
    err = (status & v1.ADC_STATUS_ERR) != 0
    rail = np.isin(codes, ADC_RAILS)
    good = codes[~err & ~rail]
    cal = channel.calibration
    out = {"efficiency_source": "input_torque", "n_input": int(codes.size), "n_input_error": int(err.sum()),
           "n_input_rail": int(rail.sum()), "torque_input_nm": math.nan, "torque_input_std_nm": math.nan,
           "torque_input_sem_nm": math.nan,
           # the engine map's figure, as reduce_point and the systematic terms made it
           "efficiency_engine_map": point.get("efficiency", math.nan),
           "efficiency_engine_map_ci95": point.get("efficiency_ci95", math.nan),
           "efficiency_engine_map_u95": point.get("efficiency_u95", math.nan),
           "efficiency_engine_map_interval95": point.get("efficiency_interval95"),
           "power_in_engine_map_w": point.get("power_in_w", math.nan),
           "power_in_w": math.nan, "efficiency": math.nan, "efficiency_sem": math.nan,
           "efficiency_ci95": math.nan, "efficiency_reason": None}
    faults = list(point.get("faults", ()))
    # the map's own complaints do not concern this efficiency (its figure is only beside it), but a figure
    # beside it outside 0..1 is still a fault, named by its key, that marks the point (a map that cannot be)
    faults = [f for f in faults if not (f.get("channel") == "efficiency" or "engine map" in f.get("reason", ""))]
    from dyno.analysis.systematic import range_fault

    map_fault = range_fault("efficiency_engine_map", out["efficiency_engine_map"])
    if map_fault is not None:
        faults.append(map_fault)
    if out["n_input_error"]:
        faults.append({"channel": "input", "severity": "warning",
                       "reason": f"{out['n_input_error']} input conversions with the AD7171 error bit excluded"})
    if out["n_input_rail"]:
        faults.append({"channel": "input", "severity": "warning",
                       "reason": f"{out['n_input_rail']} input conversions at a rail excluded"})
    nb = batch_count(t0, t1)
    if good.size < 2:
        out["efficiency_reason"] = f"{good.size} valid input torque conversions in the window"
        faults.append({"channel": "input", "reason": out["efficiency_reason"]})
    else:
        mean = float(good.mean())
        sem_c = batch_mean(good, nb)[1] if good.size >= 2 * nb else float(good.std() / math.sqrt(good.size))
        slope = cal.slope_counts_per_nm
        t_in = (mean - cal.intercept_counts) / slope + channel.bearing_loss_nm
        out.update(torque_input_nm=float(t_in), torque_input_std_nm=float(good.std() / slope),
                   torque_input_sem_nm=float(sem_c / slope))
        rp, rs, ts = point.get("rpm_primary", math.nan), point.get("rpm_secondary", math.nan), \
            point.get("torque_secondary_nm", math.nan)
        if all(isinstance(x, float) and math.isfinite(x) for x in (rp, rs, ts)) and rp > 0 and t_in > 0:
            p_in = t_in * rp * 2 * math.pi / 60
            p_out = ts * rs * 2 * math.pi / 60
            eff = p_out / p_in
            rel = math.sqrt(sum(_rel(a, b) ** 2 for a, b in (
                (point.get("torque_secondary_sem_nm"), ts), (point.get("rpm_secondary_sem"), rs),
                (out["torque_input_sem_nm"], t_in), (point.get("rpm_primary_sem"), rp))))
            out.update(power_in_w=p_in, power_out_w=p_out, efficiency=eff, efficiency_sem=eff * rel,
                       efficiency_ci95=_t975(nb - 1) * eff * rel)
            if not 0.0 <= eff <= 1.0:
                faults.append({"channel": "efficiency", "reason": f"efficiency {eff:.3f} outside 0..1: a torque "
                               "calibration does not fit this run"})
        elif not t_in > 0:
            out["efficiency_reason"] = f"input torque {t_in:.2f} N m: no power into the CVT"
            faults.append({"channel": "input", "reason": out["efficiency_reason"], "severity": "warning"})
    out["faults"] = faults
    out["valid"] = not any(f.get("severity", "error") == "error" for f in faults)
    return out


def _rel(sem, value) -> float:
    if sem is None or not isinstance(sem, float) or not math.isfinite(sem) or not value:
        return 0.0
    return sem / abs(value)


def input_systematic(point: dict, calibration_rel_out: float, channel: InputChannel,
                     driveline_max_frac: float = 0.0) -> dict:
    """The input path's systematic terms, ``efficiency_u95`` and ``efficiency_interval95`` (see the module
    docstring; the driveline's one-sided bound as :mod:`dyno.analysis.systematic` states it: the gauge is
    still after the chain).

    ``calibration_rel_out`` is the brake-side channel's term at this point
    (:func:`~dyno.analysis.systematic.calibration_rel_for`).
    """
    from dyno.analysis.systematic import half_width, interval95

    eff = point.get("efficiency", math.nan)
    t_in = point.get("torque_input_nm", math.nan)
    if not (isinstance(eff, float) and math.isfinite(eff) and isinstance(t_in, float) and t_in > 0):
        return {"efficiency_sys95": math.nan, "efficiency_sys95_calibration": math.nan,
                "efficiency_sys95_calibration_input": math.nan, "efficiency_sys95_cradle": math.nan,
                "efficiency_sys95_engine_map": 0.0, "efficiency_sys95_air": 0.0, "efficiency_sys95_driveline": math.nan,
                "efficiency_u95": math.nan, "efficiency_u95_terms": None, "efficiency_interval95": None}
    u_tare = (channel.tare or {}).get("u_nm", 0.0) or 0.0
    cal_in_rel = math.hypot(channel.calibration_rel, u_tare / t_in)
    cradle_rel = channel.bearing_loss_u_nm / t_in
    # the engine's measured torque itself (its curve against the map: dyno.analysis.measured_map)
    sem = point.get("torque_input_sem_nm", 0.0)
    sem = sem if isinstance(sem, float) and math.isfinite(sem) else 0.0
    torque_u95 = 2.0 * math.sqrt((t_in * cal_in_rel) ** 2 + channel.bearing_loss_u_nm ** 2 + sem ** 2)
    cal = 2.0 * eff * calibration_rel_out
    cal_in = 2.0 * eff * cal_in_rel
    cradle = 2.0 * eff * cradle_rel
    drive = eff * (1.0 / (1.0 - driveline_max_frac) - 1.0) if driveline_max_frac else 0.0
    sys_sym95 = math.sqrt(cal * cal + cal_in * cal_in + cradle * cradle)
    ci = point.get("efficiency_ci95", math.nan)
    ci = ci if isinstance(ci, float) and math.isfinite(ci) else 0.0
    interval = interval95(eff, math.hypot(ci, sys_sym95), None, driveline_max_frac)
    return {"torque_input_u95_nm": torque_u95,
            "efficiency_sys95": half_width(interval95(eff, sys_sym95, None, driveline_max_frac)),
            "efficiency_sys95_calibration": cal,
            "efficiency_sys95_calibration_input": cal_in, "efficiency_sys95_cradle": cradle,
            "efficiency_sys95_engine_map": 0.0, "efficiency_sys95_air": 0.0, "efficiency_sys95_driveline": drive,
            "efficiency_u95": half_width(interval),  # the interval's half-width: one 95 % statement
            "efficiency_u95_terms": {"statistical": ci, "calibration": cal, "calibration_input": cal_in,
                                     "cradle": cradle, "engine_map": 0.0, "air": 0.0, "driveline": drive},
            "efficiency_interval95": interval}


def load_channel(cfg, path) -> InputChannel:
    """The channel rig.toml ``[input_torque]`` (``cfg``) declares, with its calibration history at ``path``."""
    from dyno.analysis.calibration_history import latest, load_history
    from dyno.analysis.systematic import calibration_rel_u

    history = load_history(path)
    entry = latest(history)
    return InputChannel(entry, calibration_rel_u(history, entry), cfg.bearing_loss_nm, cfg.bearing_loss_u_nm,
                        source=str(path))


def channel_from_meta(meta: dict, tare: dict | None = None) -> InputChannel | None:
    """The channel a run was measured with (its ``meta.json`` ``input_torque``; ``tare``: its
    ``tare_input`` record), or None for a run without one."""
    rec = (meta or {}).get("input_torque")
    if not rec:
        return None
    from dyno.analysis.calibration_history import CalibrationEntry

    cal = CalibrationEntry.from_dict(rec["calibration"])
    if tare:
        cal = dataclasses.replace(cal, intercept_counts=float(tare["zero_counts"]))
    return InputChannel(cal, rec["calibration_rel"], rec["bearing_loss_nm"], rec["bearing_loss_u_nm"], tare=tare,
                        source=rec.get("source", ""))
