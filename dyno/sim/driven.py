r"""The simulated rig's centrifugal engagement, driven-side parasitic loss and torque-zero drift.

Engagement from the primary clamp
---------------------------------
The CVT is its own centrifugal clutch: the belt rides loose in the open primary
until the flyweights' axial force overcomes the primary spring preload; from then
on the moving sheave pinches the belt and the torque the primary can pass grows
with the net clamp.  Slipping tangentially on both flanks of a V of half-angle
:math:`\beta`, the belt's flank normal force is :math:`N = F_p / \sin\beta` per
flank for the axial clamp :math:`F_p` (the friction is tangential, so it has no
axial component), and the primary's slip torque is

.. math:: T_{cap}(n_p, x) = \min\Bigl(T_{max},\ \frac{2\,\mu_c\,r_p\,F_p(n_p, x)}{\sin\beta}\Bigr),
          \qquad F_p = C(x)\,n_p^2 - S_p(x) \quad (0 \text{ if negative})

with :math:`C, S_p` the same flyweight and spring tables the shift balance uses
(:mod:`dyno.sim.cvt`, from the tune) and :math:`r_p` the primary pitch radius at
the low stop (the radius the belt sits on at engagement; at larger radii the
capacity only grows, and :math:`T_{max}` caps it there).  So the engagement speed
-- the engine speed at which the secondary starts to turn -- is a property of the
tune (flyweight mass, spring preload) and of the load, as on the real CVT, not a
fixed number: :math:`n_{eng} = \sqrt{S_p/C}` at the low stop for zero load.

The flank friction :math:`\mu_c` is the world's own (:mod:`dyno.sim.cvt_friction`: drawn per world on
0.30-0.45, rubber on aluminium), not the thesis's 0.4 that the host's advisor assumes, and the clamp is
the one the sheave closes with while the engine speeds up: the ramps' and rollers' friction and the
sheave bushing take their share (:func:`dyno.sim.cvt_friction.closing_clamp_n`).

Driven-side parasitic loss
--------------------------
Bearings, seals, chain/gear mesh and windage between the CVT's output and the
torque gauge: :math:`T_{par}(\omega_s) = a + b\,\omega_s + c\,\omega_s^2` at the
secondary (``RigParams.driven_loss_nm``, off by default: the team's efficiency
truth is the belt's own, and a loss the gauge does not see makes every measured
efficiency lower than it; tests that want it switch it on).  It acts like the
existing secondary shaft drag: upstream of the gauge, so the gauge does not see
it, and it holds the shaft at rest up to :math:`a`.

Torque zero drift
-----------------
Strain-gauge bridges drift (temperature, creep of the adhesive): the ADC's zero
moves by ``adc_zero_drift_nm_per_min`` (secondary N·m per minute of simulated
time, linear; off by default), so a zero read at rest before a test and after it
differ by the drift over the test.
"""

from __future__ import annotations

import math


class Engagement:
    """Clutch torque capacity from the primary clamp (see the module docstring)."""

    def __init__(self, cvt, *, friction_coefficient: float, radius_m: float, half_angle_deg: float,
                 max_torque_nm: float) -> None:
        self.cvt = cvt
        self.k_nm_per_n = 2.0 * friction_coefficient * radius_m / math.sin(math.radians(half_angle_deg))
        self.max_torque_nm = max_torque_nm
        self.x_min = cvt.x_min

    def clamp_n(self, rpm_primary: float, x: float) -> float:
        """Net primary clamp (N) as the sheave closes (friction off), 0 while the spring holds it open."""
        from dyno.sim.cvt_friction import closing_clamp_n

        f = closing_clamp_n(self.cvt, rpm_primary, x)
        return f if f > 0.0 else 0.0

    def capacity_nm(self, rpm_primary: float, x: float) -> float:
        if rpm_primary <= 0.0:
            return 0.0
        t = self.k_nm_per_n * self.clamp_n(rpm_primary, self.x_min if x < self.x_min else x)
        return t if t < self.max_torque_nm else self.max_torque_nm

    def rpm_for_capacity(self, torque_nm: float) -> float:
        """Engine rpm at which the capacity at the low stop reaches ``torque_nm`` (quasi-static)."""
        lo, hi = 1.0, 20000.0
        if self.capacity_nm(hi, self.x_min) < torque_nm:
            return math.nan
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if self.capacity_nm(mid, self.x_min) >= torque_nm and (torque_nm > 0 or self.clamp_n(mid, self.x_min) > 0):
                hi = mid
            else:
                lo = mid
        return hi


def clamp_radius_m(params, cvt) -> float:
    """Primary pitch radius at the low stop (the radius the belt sits on when it engages)."""
    tune = cvt.tune
    if tune is not None:
        d = tune.drive
        return d.primary_radius_min_m + cvt.x_min * (d.primary_radius_max_m - d.primary_radius_min_m)
    r_sum = params.cvt_primary_radius_max_m * (1.0 + params.cvt_ratio_high)
    return r_sum / (1.0 + cvt.ratio_low)


def parasitic_nm(coeffs, omega_rad_s: float) -> float:
    """``a + b w + c w^2`` for ``w`` > 0 (the static part ``a`` alone at rest)."""
    a, b, c = coeffs
    w = omega_rad_s if omega_rad_s > 0.0 else 0.0
    return a + (b + c * w) * w


def _load_at_secondary_nm(model, omega_s_rad_s: float) -> float:
    """Quasi-static load on the secondary with the brake where it is now (kinetic, N m)."""
    p = model.params
    brake_nm = model.brake.torque_capacity_nm(model.actuator_mm, model.rotor_temp_c)
    return (brake_nm * p.gear_ratio_brake_per_secondary + p.cvt_secondary_friction_torque_nm
            + parasitic_nm(model.driveline.parasitic, omega_s_rad_s) + model.driveline_loss_nm(omega_s_rad_s))


#: what each ``*_true`` figure of the engagement plan means (recorded with them)
TRUTH_FIGURES = {
    "engagement_rpm_true": "breakaway at the low stop, engine speed rising: the closing clamp (ramp friction and "
                           "bushing off), the world's flank friction",
    "lockup_rpm_true": "the closing clamp carries the locked belt's torque (quasi-static, engine speed rising)",
    "shift_out_rpm_true": "the up-shift's start at the low stop: F_p - F_s = F_f (the frictionless balance is "
                          "lower, a back-shift's start lower still)",
    "full_shift_ratio_true": "high-stop geometric ratio over (1 - creep) at the load",
}


def characterisation_truth(model) -> dict:
    """The sim's quasi-static truths for the engagement plan, from its own model (not from a
    measurement), for the load the brake puts on the secondary now:

    * ``engagement_rpm_true``: breakaway -- the belt's slip torque at the low stop, through
      the ratio and the belt's torque loss, equals the load at rest;
    * ``lockup_rpm_true``: the capacity equals the torque the locked belt needs to carry
      that load (load / (i eta) + the bending drag) -- a quasi-static bound: on a ramp the
      lock comes later, once the slipping secondary has caught up (its inertia);
    * ``shift_out_rpm_true``: the up-shift's start at the low stop, ``F_p - F_s = F_f`` (the shift
      friction, :mod:`dyno.sim.cvt_friction`) with the secondary torque equal to the load at the speed
      it turns then (the frictionless balance would be lower, a back-shift's lower still);
    * ``cvt_friction_true``: the world's friction (clutch flank mu, ramp and helix fractions, bushings).

    Engagement and lock-up are the engine-speed-rising figures too (the closing clamp, friction off).
    * ``full_shift_ratio_true``: high-stop geometric ratio over (1 - creep) at that load.
    """
    from dyno.sim.cvt_friction import friction_n

    cvt, eng = model.cvt, model.engagement
    out: dict = {}
    if cvt.friction is not None:
        out["cvt_friction_true"] = cvt.friction.to_dict()
    out["truth_figures"] = TRUTH_FIGURES
    i_lo, i_hi = cvt.ratio_low, cvt.ratio_high
    rpm_to_rad = math.pi / 30.0
    if eng is not None:
        load0 = _load_at_secondary_nm(model, 0.0)
        eps, _ = cvt.losses(i_lo, 0.0)
        out["engagement_rpm_true"] = eng.rpm_for_capacity(load0 / (i_lo * (1.0 - eps)))
        n = out["engagement_rpm_true"]
        for _ in range(3):  # the load depends (weakly) on the speed it is carried at
            t_l = _load_at_secondary_nm(model, n / i_lo * rpm_to_rad)
            eps, _ = cvt.losses(i_lo, t_l / i_lo)
            need = (t_l / i_lo + cvt.drag_nm(i_lo)) / (1.0 - eps)
            n = eng.rpm_for_capacity(need)
        out["lockup_rpm_true"] = n

    def imbalance(rpm: float) -> float:
        t_l = _load_at_secondary_nm(model, rpm / i_lo * rpm_to_rad)
        # the belt's thrust ratio at the low stop and this load (not the running state's: the truth is
        # computed after the ramp, at the high stop)
        imb = cvt.quasi_static_imbalance_n(rpm, t_l, cvt.x_min, t_l / i_lo + cvt.drag_nm(i_lo))
        return imb - friction_n(cvt, rpm, t_l, cvt.x_min)  # the up-shift starts beyond the friction

    lo, hi = 500.0, 6000.0
    if imbalance(lo) < 0.0 < imbalance(hi):
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if imbalance(mid) < 0.0 else (lo, mid)
        out["shift_out_rpm_true"] = 0.5 * (lo + hi)
    # full shift: creep at the load carried at the high stop (taken at the shift-out speed)
    n_fs = out.get("shift_out_rpm_true", 2800.0)
    t_l = _load_at_secondary_nm(model, n_fs / i_hi * rpm_to_rad)
    t_p = (t_l / i_hi + cvt.drag_nm(i_hi))
    _, s = cvt.losses(i_hi, t_p)
    out["full_shift_ratio_true"] = i_hi / (1.0 - s)
    return out


def results_truth_hook(model):
    """A controller result hook: adds the sim's truths for the plan that produced ``results``."""

    def hook(results: dict) -> None:
        if "engagement_rpm" in results:
            results.update(characterisation_truth(model))
        if "loss_fit" in results:
            results.update(coast_down_truth(model, results))

    return hook


def coast_down_truth(model, results: dict) -> dict:
    """The true driven-side loss torque (at the secondary, brake where it is now) at the
    speeds the coast-down fitted, and the fit's largest relative error against it."""
    speeds = results.get("loss_fit", {}).get("rpm_grid") or []
    fitted = results.get("loss_fit", {}).get("torque_nm") or []
    true = [_load_at_secondary_nm(model, r * math.pi / 30.0) for r in speeds]
    out = {"loss_torque_true_nm": true}
    if true and fitted:
        out["loss_torque_max_rel_error"] = max(abs(f - t) / t for f, t in zip(fitted, true) if t > 0)
    return out


def after_drag(torque_nm: float, drag_nm: float) -> float:
    """Torque left for the brake at standstill once the shaft drag holds its share."""
    if torque_nm > drag_nm:
        return torque_nm - drag_nm
    if torque_nm < -drag_nm:
        return torque_nm + drag_nm
    return 0.0
