"""CVT of the simulated rig: shift balance, centrifugal engagement, belt losses.

Shift (quasi-static force balance with a first-order lag)
----------------------------------------------------------
The shift state is the primary sheave travel fraction ``x`` in [0, 1]
(0 = low ratio, primary open; 1 = full shift / overdrive).  The primary
pitch radius is linear in the sheave travel (``z = 2 tan(alpha) (r_p -
r_p,min)``, Messick eq. 6.12 geometry) and, to first order in the small
wrap-angle change, the belt length fixes ``r_p + r_s``:

.. math:: r_p(x) = r_{p,min} + x (r_{p,max} - r_{p,min}),\\qquad
          i(x) = \\frac{r_s}{r_p} = \\frac{R_\\Sigma - r_p(x)}{r_p(x)}

with ``R_Sigma = r_p,max (1 + i_high)``, ``r_p,min = R_Sigma/(1 + i_low)``.

Primary net clamp (Messick eq. 9.3: flyweights minus spring) and secondary
clamp (spring plus helix torque feedback, Sorge eq. 22 simplified to a
constant helix gain ``H``):

.. math:: F_p = C_{fw}\\,\\omega_p^2 - (F_{p0} + k_p z(x)),\\qquad
          F_s = F_{s0} + k_s z(x) + H\\,T_s

Setting ``F_p = F_s`` (the belt's axial force ratio taken as 1) gives the
equilibrium travel in closed form,

.. math:: x^* = \\operatorname{clip}\\left(
          \\frac{C_{fw}\\omega_p^2 - F_{p0} - F_{s0} - H T_s}{(k_p + k_s) z_{max}}, 0, 1\\right)

and the sheave follows it with a first-order lag ``tau_shift`` (belt radial
creep and sheave friction make the real shift take a few tenths of a
second).  ``dyno/tuning/actuators.py`` holds the detailed flyweight-profile
and helix forces; this simulator keeps this closed form on purpose: it is
cheap enough for the 1-2 ms inner loop, and it needs no tune file.

Engagement
----------
The CVT is its own centrifugal clutch: below the engagement speed the
primary spring holds the sheaves open and the belt slips.  The torque the
primary can pass rises smoothly from 0 at ``n_eng0`` to ``T_cap`` at
``n_eng1`` (smoothstep), and the belt locks when the slip speed crosses zero
with the required torque inside that capacity (Karnopp stick/slip).

Belt losses (simple loss model)
-------------------------------
Speed loss (creep): ``s = s_0 + s_1 |T_p| / 20 N m`` (1-3 %).
Torque loss: a load-proportional part ``eps(i)`` (radial slip and friction,
worst toward high ratio, as the thesis measured, Fig. 9.6/9.14) and a
load-independent bending/hysteresis drag referred to the primary,
``T_d = c_b (1 + 1/i)`` (bending power ~ belt speed * (1/r_p + 1/r_s)):

.. math:: T_s = i\\,\\bigl((1 - \\varepsilon(i))\\,T_p - T_d(i)\\bigr),\\qquad
          \\omega_s = \\frac{(1 - s)\\,\\omega_p}{i}

    \\varepsilon(i) = \\varepsilon_0 + a_h \\max(0, \\tfrac{i_{opt} - i}{i_{opt} - i_{high}})^2
                     + a_l \\max(0, \\tfrac{i - i_{opt}}{i_{low} - i_{opt}})^2

Overall efficiency ``eta = T_s omega_s / (T_p omega_p) = (1-s)((1-eps) - T_d/T_p)``:
about 0.80-0.82 in overdrive at light load, 0.90-0.91 near ``i_opt``,
0.89-0.90 in low ratio at full load.
"""

from __future__ import annotations

import math


class CVT:
    """Scalar CVT relations (see the module docstring)."""

    def __init__(self, *, ratio_low: float, ratio_high: float, primary_radius_max_m: float,
                 sheave_half_angle_deg: float, flyweight_coeff_kg_m: float, primary_spring_full_shift_n: float,
                 primary_spring_rate_n_per_m: float, secondary_spring_preload_n: float,
                 secondary_spring_rate_n_per_m: float, helix_gain_n_per_nm: float,
                 engage_start_rpm: float, engage_full_rpm: float, clutch_capacity_nm: float,
                 slip_base_frac: float, slip_per_20nm_frac: float, loss_frac_min: float,
                 loss_frac_high_ratio: float, loss_frac_low_ratio: float, ratio_best_eff: float,
                 bending_drag_nm: float):
        self.ratio_low = ratio_low
        self.ratio_high = ratio_high
        self.r_sum_m = primary_radius_max_m * (1.0 + ratio_high)
        self.rp_max_m = primary_radius_max_m
        self.rp_min_m = self.r_sum_m / (1.0 + ratio_low)
        self.z_max_m = 2.0 * math.tan(math.radians(sheave_half_angle_deg)) * (self.rp_max_m - self.rp_min_m)
        self.c_fw = flyweight_coeff_kg_m
        # Primary spring preload at low ratio from its full-shift force (thesis
        # eq. 9.3 bracket: 950 N - k (0.093 - R_p) 2 tan(beta) at R_p = r_p,min).
        self.primary_preload_n = primary_spring_full_shift_n - primary_spring_rate_n_per_m * self.z_max_m
        self.f0_n = self.primary_preload_n + secondary_spring_preload_n
        self.k_total_n = (primary_spring_rate_n_per_m + secondary_spring_rate_n_per_m) * self.z_max_m
        self.helix_gain = helix_gain_n_per_nm
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

    # -- shift ---------------------------------------------------------
    def ratio_of_travel(self, x: float) -> float:
        """Geometric ratio ``i = r_s / r_p`` at travel fraction ``x``."""
        rp = self.rp_min_m + x * (self.rp_max_m - self.rp_min_m)
        return (self.r_sum_m - rp) / rp

    def travel_of_ratio(self, ratio: float) -> float:
        rp = self.r_sum_m / (1.0 + ratio)
        return (rp - self.rp_min_m) / (self.rp_max_m - self.rp_min_m)

    def equilibrium_travel(self, omega_p_rad_s: float, torque_secondary_nm: float) -> float:
        """Quasi-static travel ``x*`` from the flyweight/helix force balance."""
        num = self.c_fw * omega_p_rad_s * omega_p_rad_s - self.f0_n - self.helix_gain * abs(torque_secondary_nm)
        x = num / self.k_total_n
        return 0.0 if x <= 0.0 else (1.0 if x >= 1.0 else x)

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
        """Speed loss fraction ``s``."""
        return self.s0 + self.s1 * abs(torque_primary_nm)

    def loss_frac(self, ratio: float) -> float:
        """Load-proportional torque loss fraction ``eps(i)``."""
        if ratio < self.i_opt:
            q = (self.i_opt - ratio) / (self.i_opt - self.ratio_high)
            return self.eps0 + self.a_h * q * q
        q = (ratio - self.i_opt) / (self.ratio_low - self.i_opt)
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
        s = self.creep_slip(torque_primary_nm)
        return (1.0 - s) * ((1.0 - self.loss_frac(ratio)) - self.drag_nm(ratio) / torque_primary_nm)
