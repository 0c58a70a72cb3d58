"""Driven-side loss torque from a coast-down (pure, no I/O).

With the engine cut and the brake released the belt stops coupling the engine once
the primary falls below its engagement speed; from then on the driven side (secondary
pulley, shaft, gear pair, brake shaft and rotor; inertia ``J`` referred to the
secondary) coasts down under its own losses alone:

.. math:: J\\,\\dot\\omega = -T_{loss}(\\omega),\\qquad T_{loss} = a + b\\,\\omega + c\\,\\omega^2 .

The secondary's Hall edges give the mean speed over each revolution (exactly the speed
at the period's middle when the deceleration is constant over it); the deceleration is
the central difference of neighbouring period speeds; ``a, b, c`` follow by linear least
squares of ``-J alpha`` on ``(1, w, w^2)``, and the fitted curve's 95 % band from the
fit's covariance (Student t) plus the inertia's stated uncertainty (systematic, fully
correlated: it scales the whole curve).

The torque gauge sits between the secondary and the brake: the part of the loss beyond
it (the pads' residual drag, the rotor's bearings) is in every measured torque already.
:func:`split_seen` takes that part from the gauge's mean during the coast minus its zero
at rest afterwards (the inertia torque of the brake shaft removed), leaving the loss the
gauge does not see: the one to add back to a measured efficiency
(:func:`dyno.analysis.efficiency.add_back_loss`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from dyno.acquisition.rpm import rpm_per_period

RAD_PER_RPM = math.pi / 30.0


def decelerations(s_edges_us, t_from_us: int, t_to_us: int | None = None) -> dict:
    """Per-revolution speed (rad/s) at each period's middle and the central-difference deceleration."""
    s = np.asarray(s_edges_us, dtype=np.int64)
    s = s[s >= t_from_us] if t_to_us is None else s[(s >= t_from_us) & (s <= t_to_us)]
    t_end, rpm = rpm_per_period(s)
    w = rpm * RAD_PER_RPM
    t_mid = (t_end - 30e6 / rpm) / 1e6 if rpm.size else np.zeros(0)
    if w.size < 3:
        return {"t_s": np.zeros(0), "omega_rad_s": np.zeros(0), "alpha_rad_s2": np.zeros(0)}
    alpha = (w[2:] - w[:-2]) / (t_mid[2:] - t_mid[:-2])
    return {"t_s": t_mid[1:-1], "omega_rad_s": w[1:-1], "alpha_rad_s2": alpha}


def fit_loss(omega_rad_s, alpha_rad_s2, inertia_kg_m2: float, inertia_rel_unc: float = 0.0,
             n_grid: int = 9) -> dict:
    """Least-squares ``a + b w + c w^2`` to ``-J alpha``; the curve on a speed grid with its 95 % band."""
    w = np.asarray(omega_rad_s, dtype=float)
    t = -inertia_kg_m2 * np.asarray(alpha_rad_s2, dtype=float)
    ok = np.isfinite(w) & np.isfinite(t) & (w > 0)
    w, t = w[ok], t[ok]
    if w.size < 6:
        raise ValueError(f"coast-down: {w.size} decelerating revolutions, at least 6 needed")
    X = np.column_stack([np.ones_like(w), w, w * w])
    coef, *_ = np.linalg.lstsq(X, t, rcond=None)
    resid = t - X @ coef
    dof = w.size - 3
    s2 = float(resid @ resid) / max(1, dof)
    cov = s2 * np.linalg.inv(X.T @ X)
    tq = float(stats.t.ppf(0.975, max(1, dof)))
    rpm_grid = np.linspace(w.min(), w.max(), n_grid) / RAD_PER_RPM
    g = rpm_grid * RAD_PER_RPM
    G = np.column_stack([np.ones_like(g), g, g * g])
    curve = G @ coef
    stat = tq * np.sqrt(np.einsum("ij,jk,ik->i", G, cov, G))
    sys95 = 2.0 * inertia_rel_unc * np.abs(curve)
    return {"coefficients": {"a_nm": float(coef[0]), "b_nm_per_rad_s": float(coef[1]),
                             "c_nm_per_rad_s2": float(coef[2])},
            "covariance": cov.tolist(), "rpm_grid": rpm_grid.tolist(), "torque_nm": curve.tolist(),
            "torque_ci95_nm": stat.tolist(), "torque_sys95_nm": sys95.tolist(),
            "rpm_min": float(rpm_grid[0]), "rpm_max": float(rpm_grid[-1]), "n_revolutions": int(w.size),
            "residual_sd_nm": math.sqrt(s2), "inertia_kg_m2": inertia_kg_m2, "inertia_rel_unc": inertia_rel_unc}


def loss_at(fit: dict, rpm) -> np.ndarray:
    """The fitted loss torque (N m) at secondary ``rpm`` (clamped to the fitted range: no extrapolation
    of the quadratic's shape beyond what was measured)."""
    c = fit["coefficients"]
    r = np.clip(np.asarray(rpm, dtype=float), fit["rpm_min"], fit["rpm_max"]) * RAD_PER_RPM
    return c["a_nm"] + c["b_nm_per_rad_s"] * r + c["c_nm_per_rad_s2"] * r * r


def split_seen(gauge_mean_nm: float, gauge_sem_nm: float, zero_nm: float, zero_sem_nm: float,
               inertia_beyond_gauge_kg_m2: float, mean_alpha_rad_s2: float) -> dict:
    """The constant part of the loss the gauge sees (secondary N m) with its 95 % half-width.

    The gauge reads the brake-side drag plus the inertia torque of what lies beyond it
    (``J_beyond alpha``, referred to the secondary); its zero is read at rest afterwards.
    """
    seen = gauge_mean_nm - zero_nm - inertia_beyond_gauge_kg_m2 * mean_alpha_rad_s2
    return {"seen_nm": float(seen), "seen_ci95_nm": float(1.96 * math.hypot(gauge_sem_nm, zero_sem_nm))}


def loss_band(fit: dict, rpm: float) -> tuple[float, float]:
    """The fitted loss (N m) at secondary ``rpm`` and its 95 % half-width (fit covariance and inertia).

    Beyond the fitted speeds the quadratic is extrapolated and its covariance with it: the
    band then widens as fast as the data leave ``b`` and ``c`` undetermined (honest, not pretty).
    """
    c = fit["coefficients"]
    w = rpm * RAD_PER_RPM
    g = np.array([1.0, w, w * w])
    t = c["a_nm"] + c["b_nm_per_rad_s"] * w + c["c_nm_per_rad_s2"] * w * w
    stat = 1.96 * math.sqrt(max(0.0, float(g @ np.asarray(fit["covariance"]) @ g)))
    return float(t), math.hypot(stat, 2.0 * fit.get("inertia_rel_unc", 0.0) * abs(t))


def driven_loss_keys(point: dict, loss: dict, unc: dict | None = None) -> dict:
    """A point's efficiency with the driven-side loss the gauge does not see added back (extra keys).

    Its interval (``efficiency_loss_corrected_interval95``) carries every term of the point's efficiency
    (calibration, engine map, air: ``unc`` is the run's uncertainty record,
    :func:`~dyno.analysis.systematic.interval_basis`) with the correction's own 95 % half-width in place of
    the statistics and the driveline's one-sided bound: the loss is measured now, its residual is the band.
    A value outside 0…1 is a fault naming it that marks the point as the main efficiency's does.
    """
    from dyno.analysis.efficiency import add_back_loss
    from dyno.analysis.systematic import range_fault, variant_interval95

    rs, eta, ci, p_in = (point.get(k) for k in ("rpm_secondary", "efficiency", "efficiency_ci95", "power_in_w"))
    if any(v is None or not math.isfinite(v) for v in (rs, eta, p_in)) or p_in <= 0:
        return {}
    total, total_ci = loss_band(loss["loss_fit"], rs)
    unseen = total - loss.get("seen_nm", 0.0)
    unseen_ci = math.hypot(total_ci, loss.get("seen_ci95_nm", 0.0))
    e, e_ci = add_back_loss(eta, ci if ci is not None and math.isfinite(ci) else 0.0, p_in, rs, unseen, unseen_ci)
    fit = loss["loss_fit"]
    out = {"driven_loss_nm": unseen, "driven_loss_ci95_nm": unseen_ci, "efficiency_loss_corrected": e,
           "efficiency_loss_corrected_ci95": e_ci,
           "efficiency_loss_corrected_interval95": variant_interval95(e, point, unc, driveline=False,
                                                                      drop=("statistical",), extra95=e_ci),
           "driven_loss_extrapolated": not fit["rpm_min"] <= rs <= fit["rpm_max"]}
    fault = range_fault("efficiency_loss_corrected", e)
    if fault is not None:
        out["faults"], out["valid"] = [*(point.get("faults") or ()), fault], False
    return out


def load_driven_loss(path) -> dict:
    """Read a ``driven_loss.json`` (ConfigError naming file and field on bad input)."""
    import json
    from pathlib import Path

    from dyno.errors import ConfigError

    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as exc:
        raise ConfigError(str(p), "file", f"a readable driven_loss.json ({exc.strerror or exc})") from None
    except ValueError:
        raise ConfigError(str(p), "file", "JSON (a coast-down's driven_loss.json)") from None
    if not isinstance(doc, dict) or doc.get("schema") != "dyno.driven_loss/1":
        raise ConfigError(str(p), "schema", "'dyno.driven_loss/1'")
    fit = doc.get("loss_fit")
    try:
        co = fit["coefficients"]
        vals = [float(co[k]) for k in ("a_nm", "b_nm_per_rad_s", "c_nm_per_rad_s2")]
        cov = np.asarray(fit["covariance"], dtype=float)
        rng = (float(fit["rpm_min"]), float(fit["rpm_max"]))
        seen = float(doc.get("seen_nm", 0.0)), float(doc.get("seen_ci95_nm", 0.0))
    except (TypeError, KeyError, ValueError):
        raise ConfigError(str(p), "loss_fit", "coefficients a_nm/b_nm_per_rad_s/c_nm_per_rad_s2, covariance, "
                          "rpm_min, rpm_max") from None
    if cov.shape != (3, 3) or not all(math.isfinite(v) for v in [*vals, *rng, *seen]) or not np.isfinite(cov).all():
        raise ConfigError(str(p), "loss_fit", "finite coefficients and a 3 x 3 covariance")
    return doc
