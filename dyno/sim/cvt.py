r"""CVT of the simulated rig: shift balance, centrifugal engagement, belt losses.

Shift (force balance, sheave speed proportional to the imbalance)
-----------------------------------------------------------------
The shift state is the primary sheave travel fraction ``x`` in [0, 1]
(0 = low ratio, primary open; 1 = full shift).  Primary net clamp (Messick
eq. 9.3: flyweights minus spring) and secondary clamp (springs plus helix
torque feedback, Sorge eq. 22 at steady state):

.. math:: F_p(\omega_p, x) = C(x)\,n_p^2 - S_p(x),\qquad
          F_s(T_s, x) = S_s(x) + B(x) \max(T_s, 0)

(the helix rollers lift off when the belt torque reverses).  The sheaves
move at a speed proportional to the imbalance (belt radial creep and sheave
friction act like a damper), ``dx/dt = (F_p - F_s) / (K_ref tau_shift)``
with ``K_ref`` the springs' force change over the full travel, so near a
stable balance this is a first-order lag of time constant ``tau_shift``
towards the quasi-static ratio; ``x`` stops at the ratio end stops.  With the
world's friction attached (``CVT.friction``, :mod:`dyno.sim.cvt_friction`: the
primary's ramps and rollers, the secondary's helix, the sheave bushings) only
the imbalance beyond the friction ``F_f`` moves the sheaves,
``dx/dt = D(F_p - F_s; F_f) / (K_ref tau_shift)`` with the dead band
``D(u; F_f) = sign(u) max(|u| - F_f, 0)``: the up-shift needs ``F_p - F_s > F_f``,
the back-shift ``F_p - F_s < -F_f`` (a hysteresis).

Two sources for ``C, S_p, S_s, B`` and the ratio ``i(x)``, both tabulated
over ``x`` once at start-up (the inner loop only interpolates):

* a CVT tune file (``RigParams.cvt_tune_path``, default
  ``calibration/tunes/cvtech-stock.toml``) through the public functions of
  :mod:`dyno.tuning.actuators` (flyweight profile, spring, helix, belt
  geometry), when that package and file are available;
* otherwise a self-contained closed form: ``C`` constant (a flyweight
  coefficient), linear springs, constant helix gain ``H``, and the ratio
  from ``r_p + r_s = const`` between the two ratio end stops.
Belt thrust ratio
-----------------
With a tune the simulated rig's default (``RigParams.cvt_belt_thrust_model =
"full"``) is the full belt model's thrust ratio from the belt table's cells
(:mod:`dyno.sim.belt_thrust`).  Without a tune (or without a table) the belt
passes the primary clamp to the secondary unchanged (``F_p = F_s`` at balance).
With a belt friction coefficient ``f`` (and a tune) the primary clamp sets the
belt tensions and the belt then *requires* a secondary thrust ``F_s,belt``, so the imbalance is ``F_s,belt - F_s``.
``F_s,belt = kappa F_p`` with the thrust ratio ``kappa(x, T_p, F_p; f)``
re-evaluated every ``belt_update_cells`` calls of :meth:`CVT.shift` (kappa
varies slowly next to the 0.4 s shift lag, and at a steady point it is
evaluated at that point, so the steady ratio is exact).  The true kappa comes
from ``belt_thrust_model``: ``"capstan"`` (Gerbert's V-belt,
:func:`dyno.model.capstan.capstan_point`, which is *not* the closed form that
:mod:`dyno.tuning.fit` fits, so the fit is not validated against itself) or
``"closed_form"`` (Sorge & Cammalleri eqs. 17-18, the fitted model itself:
circular, for comparison only).  Together with ``flyweight_radius_offset_m``
(added to the tune's flyweight radius table) these are the rig's hidden
"true" parameters that the fit estimates.

Slip
----
With a tune the belt's slip (``omega_s = (1 - s) omega_p / i``) is the closed
form's elastic creep at the tune's clamp ``F_p(x, n)`` and the belt torque
(0.03-0.2 %), re-evaluated with kappa; the rest of the loss model's speed loss
moves into the torque loss so the overall efficiency is unchanged.  The
closed form is the belt tier that carries the tune's loads (the full model
finds gross slip at the stock clamp from ~10 N m, see
:mod:`dyno.sim.belt_table`); it is what the overlay's slip-consistent inverse
(:mod:`dyno.model.inverse`) inverts, and the truth records ``belt_slip`` and
the geometric ratio per point.  Without a tune, or below engagement, the loss
model's slip ``s_0 + s_1 |T_p|`` applies.

Engagement
----------
The CVT is its own centrifugal clutch: below the engagement speed the
primary spring holds the sheaves open and the belt slips.  By default the
torque the primary can pass follows the net flyweight clamp of the tune
(:mod:`dyno.sim.driven`, ``RigParams.cvt_engagement_model = "clamp"``); with
``"smoothstep"`` it rises smoothly from 0 at ``n_eng0`` to ``T_cap`` at
``n_eng1`` whatever the tune (:meth:`CVT.clutch_capacity_nm_at`).  Either way
the belt locks when the slip speed crosses zero with the required torque
inside that capacity (Karnopp stick/slip).

Belt losses (simple loss model)
-------------------------------
Speed loss (creep): ``s = s_0 + s_1 |T_p| / 20 N m`` (1-3 %).
Torque loss: a load-proportional part ``eps(i)`` (radial slip and friction,
worst toward high ratio, as the thesis measured, Fig. 9.6/9.14) and a
load-independent bending/hysteresis drag referred to the primary,
``T_d = c_b (1 + 1/i)`` (bending power ~ belt speed * (1/r_p + 1/r_s)):

.. math:: T_s = i\,\bigl((1 - \varepsilon(i))\,T_p - T_d(i)\bigr),\qquad
          \omega_s = \frac{(1 - s)\,\omega_p}{i}

    \varepsilon(i) = \varepsilon_0 + a_h \max(0, \tfrac{i_{opt} - i}{i_{opt} - i_{high}})^2
                     + a_l \max(0, \tfrac{i - i_{opt}}{i_{low} - i_{opt}})^2

Overall efficiency ``eta = T_s omega_s / (T_p omega_p) = (1-s)((1-eps) - T_d/T_p)``:
about 0.80-0.82 in overdrive at light load, 0.90-0.91 near ``i_opt``,
0.89-0.90 in low ratio at full load.

Belt losses from the belt model (``RigParams.belt_efficiency_source = "belt_model"``)
-------------------------------------------------------------------------------------
The thesis's full belt model (:mod:`dyno.model`, Table 6.1 belt) predicts a
belt efficiency of ~96-97 %, while the rig measured ~80-92 %: the real CVT has
losses the belt model does not contain (bearings, clutch, sheave friction,
rubber hysteresis).  So the loss is split into the belt model's share, from a
table of its torque and speed efficiency over ratio x primary torque
(:mod:`dyno.sim.belt_table`, computed once per machine through the overlay's
disk cache), and a parasitic remainder: the simple loss model above minus the
belt model's share at the reference torque ``T_ref`` = 18 N m,

.. math:: \varepsilon = (1 - \eta_{T,belt}(i, T_p)) + \max(0, \varepsilon(i) - (1 - \eta_{T,belt}(i, T_{ref}))),

          s = (1 - \eta_{v,belt}(i, T_p)) + \max(0, s(T_{ref}) - (1 - \eta_{v,belt}(i, T_{ref}))),

with the bending drag ``T_d`` kept whole in the remainder (the belt model's
bending is elastic).  At ``T_ref`` the overall efficiency equals the loss
model's (it stays in the thesis's measured range); away from it, the torque
dependence of the belt's share (creep grows with load, the seating loss is a
larger fraction at light load) is the belt model's.  The table covers the
simulated CVT's whole ratio range 0.72-2.4 at 8 and 18 N m, at the tune's
clamp at 3150 rpm (100 N slack without a tune); torque is clamped to that
range.  A cell where the belt model did not converge (at the stock tune's
clamp: gross slip at 18 N m at every ratio) falls back to the loss model.
"""

from __future__ import annotations

import math

import numpy as np


def _tables_closed_form(x, *, ratio_low, ratio_high, primary_radius_max_m, sheave_half_angle_deg,
                        flyweight_coeff_kg_m, primary_spring_full_shift_n, primary_spring_rate_n_per_m,
                        secondary_spring_preload_n, secondary_spring_rate_n_per_m, helix_gain_n_per_nm):
    """Closed-form balance tables.

    ``r_p + r_s = R`` (first order in the wrap-angle change), ``r_p`` linear in
    the travel; primary spring preload from its full-shift force (thesis eq.
    9.3 bracket: ``950 N - k 2 tan(beta) (0.093 - R_p)``).
    """
    r_sum = primary_radius_max_m * (1.0 + ratio_high)
    rp_min = r_sum / (1.0 + ratio_low)
    rp = rp_min + x * (primary_radius_max_m - rp_min)
    ratio = (r_sum - rp) / rp
    z = 2.0 * math.tan(math.radians(sheave_half_angle_deg)) * (rp - rp_min)
    z_max = float(z[-1])
    c_rpm2 = np.full_like(x, flyweight_coeff_kg_m * (math.pi / 30.0) ** 2)
    s_p = primary_spring_full_shift_n - primary_spring_rate_n_per_m * (z_max - z)
    s_s = secondary_spring_preload_n + secondary_spring_rate_n_per_m * z
    b_s = np.full_like(x, helix_gain_n_per_nm)
    return ratio, c_rpm2, s_p, s_s, b_s


def _tables_from_tune(tune, x, flyweight_radius_offset_m=0.0):
    """Balance tables from a CVT tune through :mod:`dyno.tuning.actuators`.

    Only public functions: the centrifugal force is ``c(x) n^2``, so it is
    evaluated at 1000 rpm and scaled; the steady-state secondary clamp is
    linear in the belt torque above zero, so two torques give ``S_s`` and ``B``.
    ``flyweight_radius_offset_m`` shifts the flyweight radius table (eq. 9.2
    with ``r + dr`` at the same ``dr/dz``): a hidden "true" rig parameter.
    """
    from dyno.tuning import actuators as act

    d = tune.drive
    rp = d.primary_radius_min_m + x * (d.primary_radius_max_m - d.primary_radius_min_m)
    rs = np.asarray(act.secondary_radius_m(tune, rp), dtype=float)
    ratio = rs / rp
    c_rpm2 = np.asarray(act.primary_centrifugal_force_n(tune, 1000.0, rp), dtype=float) / 1.0e6
    if flyweight_radius_offset_m and tune.flyweights is not None:
        fw = tune.flyweights
        _, drdz = act.flyweight_radius_m(fw, act.primary_sheave_travel_m(tune, rp))
        c_rpm2 = c_rpm2 + fw.count * fw.mass_each_kg * flyweight_radius_offset_m * np.asarray(drdz) * (
            math.pi / 30.0) ** 2
    s_p = np.asarray(act.primary_spring_force_n(tune, rp), dtype=float)
    f0 = np.asarray(act.secondary_axial_force_n(tune, 0.0, rs), dtype=float)
    f10 = np.asarray(act.secondary_axial_force_n(tune, 10.0, rs), dtype=float)
    b_s = (f10 - f0) / 10.0
    return ratio, c_rpm2, s_p, f0, b_s


#: the low-ratio end of the loss model's shape: the thesis's measured efficiencies (Fig. 9.6/9.14) and the
#: 2019 logs reach ~2.4; beyond it (the stock drive's geometry goes to 3.06) the quadratic carries on
LOSS_SHAPE_RATIO_LOW = 2.4


class CVT:
    """Scalar CVT relations (see the module docstring)."""

    def __init__(self, *, ratio_low: float, ratio_high: float, primary_radius_max_m: float,
                 sheave_half_angle_deg: float, flyweight_coeff_kg_m: float, primary_spring_full_shift_n: float,
                 primary_spring_rate_n_per_m: float, secondary_spring_preload_n: float,
                 secondary_spring_rate_n_per_m: float, helix_gain_n_per_nm: float,
                 shift_time_constant_s: float,
                 engage_start_rpm: float, engage_full_rpm: float, clutch_capacity_nm: float,
                 slip_base_frac: float, slip_per_20nm_frac: float, loss_frac_min: float,
                 loss_frac_high_ratio: float, loss_frac_low_ratio: float, ratio_best_eff: float,
                 bending_drag_nm: float, tune=None, n_table: int = 400,
                 belt_friction_coefficient: float | None = None, flyweight_radius_offset_m: float = 0.0,
                 belt_update_cells: int = 25, belt_table=None, belt_reference_torque_nm: float = 18.0,
                 belt_thrust_model: str = "capstan", thrust_table=None):
        if belt_thrust_model not in ("full", "capstan", "closed_form"):
            raise ValueError(f"belt_thrust_model: 'full', 'capstan' or 'closed_form', got {belt_thrust_model!r}")
        self.belt_thrust_model = belt_thrust_model
        self.belt_table = belt_table
        self.t_ref = belt_reference_torque_nm
        self.tau_shift_s = shift_time_constant_s
        self.n_eng0 = engage_start_rpm
        self.n_eng1 = engage_full_rpm
        self.clutch_capacity_nm = clutch_capacity_nm
        self.s0 = slip_base_frac
        self.s1 = slip_per_20nm_frac / 20.0
        self.eps0 = loss_frac_min
        self.a_h = loss_frac_high_ratio
        self.a_l = loss_frac_low_ratio
        self.i_opt = ratio_best_eff
        self.c_bend = bending_drag_nm
        self.tune = tune
        # the world's friction (dyno.sim.cvt_friction.CvtFriction), attached by the rig; None = frictionless
        self.friction = None
        x = np.linspace(0.0, 1.0, n_table + 1)
        if tune is not None:
            ratio, c_rpm2, s_p, s_s, b_s = _tables_from_tune(tune, x, flyweight_radius_offset_m)
            self.source = f"tune {tune.name!r} via dyno.tuning.actuators"
        else:
            ratio, c_rpm2, s_p, s_s, b_s = _tables_closed_form(
                x, ratio_low=ratio_low, ratio_high=ratio_high, primary_radius_max_m=primary_radius_max_m,
                sheave_half_angle_deg=sheave_half_angle_deg, flyweight_coeff_kg_m=flyweight_coeff_kg_m,
                primary_spring_full_shift_n=primary_spring_full_shift_n,
                primary_spring_rate_n_per_m=primary_spring_rate_n_per_m,
                secondary_spring_preload_n=secondary_spring_preload_n,
                secondary_spring_rate_n_per_m=secondary_spring_rate_n_per_m, helix_gain_n_per_nm=helix_gain_n_per_nm)
            self.source = "closed-form balance (dyno.sim.cvt)"
        # End stops: the requested ratio range, inside what the geometry allows.
        self.x_min = float(np.interp(-min(ratio_low, ratio[0]), -ratio, x))
        self.x_max = float(np.interp(-max(ratio_high, ratio[-1]), -ratio, x))
        self.ratio_low = float(np.interp(self.x_min, x, ratio))
        self.ratio_high = float(np.interp(self.x_max, x, ratio))
        self._n = n_table
        self._ratio = ratio.tolist()
        self._x_grid = x
        self._ratio_arr = ratio
        # Pre-combine per cell for the inner loop: F_p - F_s = C n^2 - S - B T.
        self._c = c_rpm2.tolist()
        self._s = (s_p + s_s).tolist()
        self._b = b_s.tolist()
        # Belt thrust-ratio mode keeps the two sides apart (kappa multiplies F_p only).
        self._sp = s_p.tolist()
        self._ss = s_s.tolist()
        self._belt_params = None
        self._kappa = 1.0
        self._belt_creep = None
        self._belt_every = max(int(belt_update_cells), 1)
        self._belt_count = 0
        self._creep_params = None
        self.thrust_table = thrust_table if thrust_table is not None else belt_table
        if belt_thrust_model == "full" and belt_friction_coefficient is None:
            if tune is not None and self.thrust_table is not None and self.thrust_table.kappa is not None:
                self._belt_params = self._creep_params = "full"  # the table's full-model cells: kappa and creep
                self.source += ", full-model belt thrusts (the belt table)"
            elif tune is not None:
                from dyno.tuning.tune import model_params_for

                self._creep_params = model_params_for(tune)  # no table: no thrust ratio (F_p = F_s)
        elif belt_friction_coefficient is not None:
            if belt_thrust_model == "full":
                belt_thrust_model = self.belt_thrust_model = "capstan"  # a friction given: the capstan tier's
            if tune is None:
                raise ValueError("belt_friction_coefficient needs a CVT tune (the belt geometry)")
            from dyno.model.params import BeltParams
            from dyno.tuning.tune import model_params_for

            self._belt_params = model_params_for(tune, BeltParams(friction_coefficient=belt_friction_coefficient))
            self._creep_params = self._belt_params
            self.source += f", {belt_thrust_model} belt thrusts (f = {belt_friction_coefficient:g})"
        elif tune is not None:
            from dyno.tuning.tune import model_params_for

            # The belt's slip at the tune's clamp (see "Slip" in the module docstring).
            self._creep_params = model_params_for(tune)
        # Force scale of the lag: the springs' force change over the travel.
        self.k_ref_n = float(max(abs((s_p[-1] + s_s[-1]) - (s_p[0] + s_s[0])), 1.0))

    # -- shift ---------------------------------------------------------
    def _lookup(self, table: list, x: float) -> float:
        u = x * self._n
        if u <= 0.0:
            return table[0]
        if u >= self._n:
            return table[-1]
        j = int(u)
        f = u - j
        return table[j] + f * (table[j + 1] - table[j])

    def ratio_of_travel(self, x: float) -> float:
        """Geometric ratio ``i = r_s / r_p`` at travel fraction ``x``."""
        return self._lookup(self._ratio, x)

    def travel_of_ratio(self, ratio: float) -> float:
        return float(np.interp(-ratio, -self._ratio_arr, self._x_grid))

    def force_imbalance_n(self, rpm_primary: float, torque_secondary_nm: float, x: float) -> float:
        """``F_p - F_s`` (N): > 0 shifts up (towards overdrive)."""
        u = x * self._n
        j = 0 if u <= 0.0 else (self._n - 1 if u >= self._n else int(u))
        f = min(max(u - j, 0.0), 1.0)
        c, s, b = self._c, self._s, self._b
        cc = c[j] + f * (c[j + 1] - c[j])
        ss = s[j] + f * (s[j + 1] - s[j])
        t = torque_secondary_nm if torque_secondary_nm > 0.0 else 0.0
        bb = b[j] + f * (b[j + 1] - b[j])
        if self._belt_params is not None:
            # F_s,belt - F_s = kappa F_p - (S_s + B T); F_p <= 0 (spring holds the sheave
            # open) keeps kappa out of it, so the imbalance still closes the primary.
            sp, sss = self._sp, self._ss
            f_p = cc * rpm_primary * rpm_primary - (sp[j] + f * (sp[j + 1] - sp[j]))
            f_s = sss[j] + f * (sss[j + 1] - sss[j]) + bb * t
            return (self._kappa * f_p if f_p > 0.0 else f_p) - f_s
        return cc * rpm_primary * rpm_primary - ss - bb * t

    def primary_force_n(self, rpm_primary: float, x: float) -> float:
        """Net primary clamp ``F_p = C n^2 - S_p`` (belt mode tables)."""
        u = min(max(x * self._n, 0.0), float(self._n))
        j = min(int(u), self._n - 1)
        f = u - j
        c, sp = self._c, self._sp
        return (c[j] + f * (c[j + 1] - c[j])) * rpm_primary * rpm_primary - (sp[j] + f * (sp[j + 1] - sp[j]))

    def shift_coefficients(self, x: float) -> tuple[float, float]:
        """``(C, B)`` at travel fraction ``x``, interpolated in the tables of ``F_p - F_s = C n^2 - S - B T``: the
        flyweights' force per rpm squared (N/rpm^2) and the helix's per N m of secondary torque (N/(N m))."""
        u = x * self._n
        j = 0 if u <= 0.0 else (self._n - 1 if u >= self._n else int(u))
        f = min(max(u - j, 0.0), 1.0)
        c, b = self._c, self._b
        return c[j] + f * (c[j + 1] - c[j]), b[j] + f * (b[j + 1] - b[j])

    @property
    def thrust_ratio(self) -> float:
        """The thrust ratio ``kappa`` (``F_s,belt = kappa F_p``) the balance uses now; 1 without a belt model."""
        return self._kappa if self._belt_params is not None else 1.0

    @property
    def belt_params(self):
        """The belt model of the thrust ratio: ``"full"`` (the thrust table's cells), the model's parameters
        (capstan or closed form), or None (no thrust ratio: ``F_p = F_s``)."""
        return self._belt_params

    @property
    def creep_params(self):
        """The belt model of the creep slip: ``"full"``, the model's parameters, or None (the loss model's slip)."""
        return self._creep_params

    def update_belt(self, x: float, rpm_primary: float, torque_primary_nm: float) -> None:
        """Re-evaluate the belt's slip (and, in belt mode, the thrust ratio ``kappa``) at this state."""
        creep, kappa = self.belt_state(x, rpm_primary, torque_primary_nm)
        self._belt_creep = creep
        if kappa is not None:
            self._kappa = kappa

    def belt_state(self, x: float, rpm_primary: float, torque_primary_nm: float) -> tuple:
        """(creep slip or None, thrust ratio kappa or None = keep the current one) at this state; pure
        (:func:`dyno.sim.belt_thrust.belt_state`)."""
        from dyno.sim.belt_thrust import belt_state

        return belt_state(self, x, rpm_primary, torque_primary_nm)

    def quasi_static_imbalance_n(self, rpm_primary: float, torque_secondary_nm: float, x: float,
                                 torque_primary_nm: float) -> float:
        """``force_imbalance_n`` with the belt's thrust ratio evaluated at this state (not the running one):
        for the sim's quasi-static truths; leaves the running state alone."""
        if self._creep_params is None or self._belt_params is None:
            return self.force_imbalance_n(rpm_primary, torque_secondary_nm, x)
        saved = self._kappa
        _, kappa = self.belt_state(x, rpm_primary, torque_primary_nm)
        try:
            if kappa is not None:
                self._kappa = kappa
            return self.force_imbalance_n(rpm_primary, torque_secondary_nm, x)
        finally:
            self._kappa = saved

    def shift(self, x: float, rpm_primary: float, torque_secondary_nm: float, dt_s: float,
              torque_primary_nm: float = 0.0) -> float:
        """Travel after ``dt_s``: ``dx/dt = (F_p - F_s) / (K_ref tau)``, end stops.

        ``torque_primary_nm`` (belt input torque) only matters in belt mode.
        """
        if self._creep_params is not None:
            if self._belt_count % self._belt_every == 0:
                self.update_belt(x, rpm_primary, torque_primary_nm)
            self._belt_count += 1
        imb = self.force_imbalance_n(rpm_primary, torque_secondary_nm, x)
        if self.friction is not None:
            from dyno.sim.cvt_friction import friction_n
            from dyno.sim.driven import after_drag as dead_band  # the same Coulomb band: 0 inside +-friction

            imb = dead_band(imb, friction_n(self, rpm_primary, torque_secondary_nm, x))
        dx = imb * dt_s / (self.k_ref_n * self.tau_shift_s)
        x = x + dx
        return self.x_min if x < self.x_min else (self.x_max if x > self.x_max else x)

    def equilibrium_travel(self, rpm_primary: float, torque_secondary_nm: float) -> float:
        """Quasi-static travel where ``F_p = F_s`` (end stop if none), for tests and plots: the frictionless
        balance, the middle of the friction's hysteresis band."""
        xs = np.linspace(self.x_min, self.x_max, 401)
        r = np.array([self.force_imbalance_n(rpm_primary, torque_secondary_nm, v) for v in xs])
        if r[0] <= 0.0:
            return self.x_min
        if r[-1] >= 0.0:
            return self.x_max
        k = int(np.argmax(r <= 0.0))
        return float(xs[k - 1] + (xs[k] - xs[k - 1]) * r[k - 1] / (r[k - 1] - r[k]))

    # -- engagement ----------------------------------------------------
    def clutch_capacity_nm_at(self, rpm_primary: float) -> float:
        """Torque the primary can pass at engine speed ``rpm`` (smoothstep)."""
        if rpm_primary <= self.n_eng0:
            return 0.0
        if rpm_primary >= self.n_eng1:
            return self.clutch_capacity_nm
        q = (rpm_primary - self.n_eng0) / (self.n_eng1 - self.n_eng0)
        return self.clutch_capacity_nm * q * q * (3.0 - 2.0 * q)

    # -- losses ----------------------------------------------------------
    def creep_slip(self, torque_primary_nm: float) -> float:
        """Speed loss fraction ``s`` of the simple loss model."""
        return self.s0 + self.s1 * abs(torque_primary_nm)

    def losses(self, ratio: float, torque_primary_nm: float) -> tuple[float, float]:
        """``(eps, s)``: torque loss fraction and slip at this ratio and belt torque.

        Simple loss model, or belt-model share + parasitic remainder when a
        belt table is attached (see the module docstring).  With a tune the
        slip is the belt's (closed-form creep at the tune's clamp, see "Slip")
        and the rest of the speed loss moves into the torque loss: the
        product (1 - eps)(1 - s), the overall efficiency, is unchanged.
        """
        eps, s = self._losses_before_slip(ratio, torque_primary_nm)
        creep = self._belt_creep
        if creep is not None and creep < 1.0:
            eps = 1.0 - (1.0 - eps) * (1.0 - s) / (1.0 - creep)
            s = creep
        return eps, s

    def _losses_before_slip(self, ratio: float, torque_primary_nm: float) -> tuple[float, float]:
        tab = self.belt_table
        if tab is not None:
            t = abs(torque_primary_nm)
            here = tab.lookup(ratio, t)
            ref = tab.lookup(ratio, self.t_ref) if here is not None else None
            if ref is not None:
                eps_par = self.empirical_loss_frac(ratio) - (1.0 - ref[0])
                s_par = self.s0 + self.s1 * self.t_ref - (1.0 - ref[1])
                eps = (1.0 - here[0]) + (eps_par if eps_par > 0.0 else 0.0)
                s = (1.0 - here[1]) + (s_par if s_par > 0.0 else 0.0)
                return eps, s
        return self.empirical_loss_frac(ratio), self.creep_slip(torque_primary_nm)

    def belt_share(self, ratio: float, torque_primary_nm: float):
        """``(eps_belt, s_belt)`` of the belt model here, or None (no table / failed cell)."""
        if self.belt_table is None:
            return None
        v = self.belt_table.lookup(ratio, abs(torque_primary_nm))
        return None if v is None else (1.0 - v[0], 1.0 - v[1])

    def loss_frac(self, ratio: float, torque_primary_nm: float | None = None) -> float:
        """Torque loss fraction: ``eps(i)``, or with a belt table the belt share + remainder."""
        if self.belt_table is None:
            return self.empirical_loss_frac(ratio)
        return self.losses(ratio, self.t_ref if torque_primary_nm is None else torque_primary_nm)[0]

    def empirical_loss_frac(self, ratio: float) -> float:
        """Load-proportional torque loss fraction ``eps(i)`` of the simple loss model."""
        if ratio < self.i_opt:
            q = (self.i_opt - ratio) / (self.i_opt - self.ratio_high)
            return self.eps0 + self.a_h * q * q
        q = (ratio - self.i_opt) / (LOSS_SHAPE_RATIO_LOW - self.i_opt)
        return self.eps0 + self.a_l * q * q

    def drag_nm(self, ratio: float) -> float:
        """Load-independent bending drag referred to the primary."""
        return self.c_bend * (1.0 + 1.0 / ratio)

    def secondary_torque_nm(self, torque_primary_nm: float, ratio: float, eta_m: float, drag_nm: float) -> float:
        """Belt output torque for an input torque (forward or reverse power flow).

        Forward (``T_p > 0``): ``T_s = i (eta_m T_p - T_d)``; reverse (engine
        braking, the secondary drives): ``T_s = i (T_p / eta_m - T_d)``.  The
        drag always opposes the (positive) belt motion.
        """
        if torque_primary_nm >= 0.0:
            return ratio * (eta_m * torque_primary_nm - drag_nm)
        return ratio * (torque_primary_nm / eta_m - drag_nm)

    def efficiency(self, torque_primary_nm: float, ratio: float) -> float:
        """Steady-state overall efficiency ``(1 - s)((1 - eps) - T_d / T_p)``."""
        if torque_primary_nm <= 0.0:
            return 0.0
        eps, s = self.losses(ratio, torque_primary_nm)
        return (1.0 - s) * ((1.0 - eps) - self.drag_nm(ratio) / torque_primary_nm)
