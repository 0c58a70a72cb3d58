"""Friction brake of the simulated rig: actuator, spring, master cylinder, pads, rotor heat.

Actuator and spring
-------------------
A screw linear actuator (constant speed ``v_act``, end stops at 0 and
``a_max``) pushes the master-cylinder pushrod through a spring.  No force
until the free travel ``a_0`` is taken up (pushrod slack and the master
cylinder's port closing), then the spring force rises linearly, which is why
the thesis put the spring there (less sensitivity of pressure to position):

.. math:: F_{rod} = k_{spr} \\max(0, a - a_0)

Pads and torque
---------------
Line pressure ``p = F_rod / A_mc`` clamps the caliper piston ``A_cal``; two
pad faces at the effective radius ``r_eff``:

.. math:: T_{cap} = T_{res} + \\mu(T_r)\\, 2 r_{eff} \\frac{A_{cal}}{A_{mc}} F_{rod}

``T_res`` is the pads' residual drag.  This is a *capacity*: kinetic
friction opposes the rotor's motion with ``T_cap``; at rest the brake holds
any torque up to ``T_cap`` (no reverse drive, no chatter at zero speed; the
integrator in :mod:`dyno.sim.physics` does the stick/slip logic).

Pad friction fades linearly with rotor temperature down to a floor:

.. math:: \\mu(T_r) = \\mu_0 \\max(\\mu_{floor},\\ 1 - c_\\mu (T_r - 25\\,^\\circ C))

Rotor heat
----------
Lumped rotor, heated by all of the brake power, cooled by convection whose
coefficient grows with rotor speed (vented rotor):

.. math:: C_r \\frac{dT_r}{dt} = T_{brake}\\,\\omega_b - (h_0 + h_1 \\omega_b)(T_r - T_{amb})

Integrated exactly over a step with the power and coefficient held
(exponential relaxation), so any step size is stable.
"""

from __future__ import annotations

import math


class Brake:
    """Scalar brake relations (see the module docstring)."""

    def __init__(self, *, actuator_speed_mm_s: float, actuator_travel_mm: float, free_travel_mm: float,
                 spring_rate_n_per_mm: float, master_cylinder_bore_mm: float, caliper_piston_bore_mm: float,
                 pad_radius_m: float, mu_cold: float, mu_fade_per_c: float, mu_floor_frac: float,
                 residual_drag_nm: float, rotor_heat_capacity_j_per_k: float, rotor_cooling_w_per_k: float,
                 rotor_cooling_w_per_k_per_rad_s: float, ambient_c: float):
        self.v_act_mm_s = actuator_speed_mm_s
        self.a_max_mm = actuator_travel_mm
        self.a0_mm = free_travel_mm
        self.k_spr = spring_rate_n_per_mm
        self.gain_m = 2.0 * pad_radius_m * (caliper_piston_bore_mm / master_cylinder_bore_mm) ** 2
        self.mu_cold = mu_cold
        self.mu_fade = mu_fade_per_c
        self.mu_floor = mu_floor_frac
        self.t_res_nm = residual_drag_nm
        self.c_rotor = rotor_heat_capacity_j_per_k
        self.h0 = rotor_cooling_w_per_k
        self.h1 = rotor_cooling_w_per_k_per_rad_s
        self.t_amb_c = ambient_c

    def move_actuator_mm(self, position_mm: float, direction: int, dt_s: float) -> float:
        """New actuator position after ``dt_s`` at constant speed, end stops."""
        if direction == 0:
            return position_mm
        a = position_mm + (self.v_act_mm_s * dt_s if direction > 0 else -self.v_act_mm_s * dt_s)
        return 0.0 if a < 0.0 else (self.a_max_mm if a > self.a_max_mm else a)

    def pushrod_force_n(self, position_mm: float) -> float:
        d = position_mm - self.a0_mm
        return self.k_spr * d if d > 0.0 else 0.0

    def mu(self, rotor_temp_c: float) -> float:
        f = 1.0 - self.mu_fade * (rotor_temp_c - 25.0)
        return self.mu_cold * (f if f > self.mu_floor else self.mu_floor)

    def torque_capacity_nm(self, position_mm: float, rotor_temp_c: float) -> float:
        """Brake-shaft friction torque capacity ``T_cap`` (N*m)."""
        return self.t_res_nm + self.mu(rotor_temp_c) * self.gain_m * self.pushrod_force_n(position_mm)

    def rotor_temp_after_c(self, rotor_temp_c: float, brake_power_w: float, omega_brake_rad_s: float,
                           dt_s: float) -> float:
        """Exact lumped update with power and cooling held over ``dt_s``."""
        h = self.h0 + self.h1 * abs(omega_brake_rad_s)
        t_inf = self.t_amb_c + brake_power_w / h
        return t_inf + (rotor_temp_c - t_inf) * math.exp(-h * dt_s / self.c_rotor)
