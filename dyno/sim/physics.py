"""Physics of the simulated CVT dynamometer (engine, CVT, brake, sensors).

Public API: :class:`RigParams`, :class:`SensorEvent`, :class:`Truth`,
:class:`RigModel`.  The model is deterministic under its seed and has no
clock of its own: time advances only through :meth:`RigModel.step`.

Drivetrain
----------
Two rotating bodies: the crank (engine, flywheel, primary pulley; inertia
``J_e``) and the secondary side (secondary pulley and shaft, plus the 32:61
gear pair and the brake shaft with the rotor reflected by ``g^2``,
``g = 32/61``; inertia ``J_s``).  With the belt gripping (clutch locked) the
secondary speed is tied to the crank speed, ``omega_s = k omega_e``,
``k = (1 - s)/i`` (see :mod:`dyno.sim.cvt`), and the pair is one degree of
freedom:

.. math:: J_e \\dot\\omega_e = T_e - T_p,\\qquad
          J_s k \\dot\\omega_e = i(\\eta_m T_p - T_d) - T_L

    \\Rightarrow\\ \\dot\\omega_e = \\frac{i \\eta_m T_e - i T_d - T_L}{J_s k + i \\eta_m J_e}

where ``T_L = g T_brake`` is the brake's kinetic friction referred to the
secondary.  When the needed belt torque ``T_p`` exceeds what the
centrifugal engagement can pass, or below the engagement speed, the two
bodies move separately (belt slipping with ``T_p = +-T_cap``), with
Karnopp stick/slip for the brake at zero speed (the brake holds up to its
capacity and never drives the shaft backwards).  When the ratio ``k``
changes (shifting) the two speeds are kept consistent by the belt impulse
that conserves ``i J_e omega_e + J_s omega_s``.

The ratio ``i`` follows the flyweight/helix force balance of the CVT tune
``RigParams.cvt_tune_path`` through :mod:`dyno.tuning.actuators` (closed-form
fallback with ``cvt_tune_path=None``), between the end stops
``cvt_ratio_low``/``cvt_ratio_high``; see :mod:`dyno.sim.cvt`.  The belt's thrust ratio is the full belt
model's (:mod:`dyno.sim.belt_thrust`), the clutch's, ramps' and helix's friction the world's own
(:mod:`dyno.sim.cvt_friction`); the other hidden parameters are in :mod:`dyno.sim.rig_params`.

Belt efficiency (``belt_efficiency_source``): "belt_model" (default) splits the
CVT loss into the full belt model's share, from a ratio x torque table solved
once per machine into the belt model's overlay cache (:mod:`dyno.sim.belt_table`,
at the tune's clamp, ~60 s from an empty cache), and a documented parasitic remainder (the simple
loss model minus the belt's share at 18 N m: bearings, clutch, sheave friction,
hysteresis), so the overall efficiency stays in the thesis's measured
80-92 %; "loss_model" is the simple loss model alone (see :mod:`dyno.sim.cvt`).
The truth's efficiency is always the model's own power balance.  With a tune the
belt's slip is its closed-form creep at the tune's clamp (the truth records it as
``belt_slip`` with ``ratio_geometric``; see "Slip" in :mod:`dyno.sim.cvt`).

The torque gauge sits on the brake shaft between the gear and the rotor, so
it reads ``T_brake + J_rotor alpha_b``: equal to the belt's output torque
``T_s / g`` only in steady state (in a transient the secondary pulley's own
inertia torque is not seen).

Integration: a fixed grid of ``max_substep_s`` (4 ms) cells in absolute time,
buffered ahead of the caller (the events do not depend on how the host slices
time); explicit for the mean speeds, exact exponentials for the rotor
temperature and lock-in filter, exact within-cell edge timing.

Sensor outputs, truth: :mod:`dyno.sim.rig_signals`; parameters: :mod:`dyno.sim.rig_params`.
"""

from __future__ import annotations

import math
from operator import attrgetter

import numpy as np

from dyno.sim.brake import Brake
from dyno.sim.cvt import CVT
from dyno.sim.driveline import Driveline
from dyno.sim.driven import Engagement, after_drag, clamp_radius_m
from dyno.sim.engine import RAD_S_PER_RPM, RPM_PER_RAD_S, Engine, EngineMap
from dyno.sim.input_torque import CradleLoadCell
from dyno.sim.rig_params import RigParams, belt_tables_for, load_sim_tune
from dyno.sim.rig_params import resolve_map_path
from dyno.sim.kill_chain import KillChain
from dyno.sim.pads import PadsRecord
from dyno.sim.rig_signals import TWO_PI, SensorEvent, SensorSignals, Truth
from dyno.sim.tune_deviation import parts_on_the_rig
from dyno.sim.cvt_friction import attach_friction
from dyno.sim.world import realise

__all__ = ["RigModel"]


def _part_attribute(part: str, name: str, doc: str, writable: bool = True) -> property:
    """The model's attribute that is the attribute ``name`` of its part ``part`` (read, and set if ``writable``)."""
    def get(self):
        return getattr(getattr(self, part), name)

    def set_(self, value) -> None:
        setattr(getattr(self, part), name, value)

    return property(get, set_ if writable else None, doc=doc)


class RigModel:
    """The simulated rig.  See the module docstring for the physics.

    Its parts: ``kill`` (the ignition's :class:`~dyno.sim.kill_chain.KillChain`), ``pads`` (the brake pads'
    :class:`~dyno.sim.pads.PadsRecord`), ``signals`` (Hall edges and torque conversions,
    :class:`~dyno.sim.rig_signals.SensorSignals`), ``input_cell`` (the cradle's load cell,
    :class:`~dyno.sim.input_torque.CradleLoadCell`); the attributes below that belong to a part are that
    part's, read and set through the model.

    Inputs (attributes set by the device/actuator emulation):
    ``throttle_frac`` (0 idle .. 1 full), ``engine_enabled`` (False = the Pi
    opens the kill chain), ``actuator_dir`` (the enable: +1/-1 powered, 0 stop),
    ``relay_dir`` (the direction relay's coil: +1 apply, -1 release = rest;
    set by a powered ``actuator_dir``, or alone by a driver that switches it
    with the enable off).  The actuator moves the way the relay's contacts
    point once they have made, ``relay_transfer_s`` after the coil changed,
    unpowered meanwhile.
    Fault knobs: ``stuck_hall`` (set of channel names that give no edges),
    ``adc_error_prob``.
    """

    # the kill chain's inputs and wiring faults (dyno.sim.kill_chain), and its record
    engine_enabled = _part_attribute("kill", "engine_enabled", "The Pi's switch in the kill chain (GPIO24).")
    nano_enable = _part_attribute("kill", "nano_enable", "The Nano's run-enable in the kill chain (D7).")
    estop_open = _part_attribute("kill", "estop_open", "The E-stop chain's NC contact is open.")
    pi_switch_welded = _part_attribute("kill", "pi_switch_welded", "Drill: the Pi's switch conducts always.")
    run_enable_shorted = _part_attribute("kill", "run_enable_shorted", "Drill: the Nano's run-enable conducts always.")
    kill_lead_open = _part_attribute("kill", "kill_lead_open", "Drill: the magneto's kill lead is open.")
    ignition_on = _part_attribute("kill", "ignition_on", "The kill relay is energised.", writable=False)
    magneto_fires = _part_attribute("kill", "magneto_fires", "The ignition sparks.", writable=False)
    ignition_log = _part_attribute("kill", "log", "``(t_s, on, by)`` at every change of the chain.", writable=False)
    ignition_cut_mm = _part_attribute("kill", "cut_mm", "The actuator's true position at each opening.",
                                      writable=False)
    ignition_enabled_at_s = _part_attribute("kill", "enabled_at_s", "When the chain first closed (true time).",
                                            writable=False)
    # the pads' record (dyno.sim.pads)
    pads_off_at_s = _part_attribute("pads", "off_at_s", "When the pads last left the rotor (true time).",
                                    writable=False)
    startup_released_at_s = _part_attribute("pads", "startup_released_at_s",
                                            "When a brake that started applied first let go (true time).",
                                            writable=False)
    # the sensors' fault knobs (dyno.sim.rig_signals, dyno.sim.input_torque)
    adc_error_prob = _part_attribute("signals", "adc_error_prob", "Probability of the torque ADC's error bit.")
    adc_stuck = _part_attribute("signals", "adc_stuck", "Drill: every torque conversion repeats one code.")
    input_fitted = _part_attribute("input_cell", "fitted", "The cradle's load cell is fitted.", writable=False)
    input_error_prob = _part_attribute("input_cell", "error_prob", "Probability of the input ADC's error bit.")
    input_stuck = _part_attribute("input_cell", "stuck", "Drill: every input conversion repeats one code.")

    def __init__(self, params: RigParams | None = None, seed: int = 0):
        p = params if params is not None else RigParams()
        nominal = EngineMap.from_csv(resolve_map_path(p.engine_map_path))
        # this seed's own engine, sensor and day (dyno.sim.world): p becomes the rig as it is
        p, rpm, torque_true_nm, self.world = realise(p, seed, nominal.rpm, nominal.torque_nm)
        self.params = p
        self.seed = seed
        self.engine_map = EngineMap(rpm, torque_true_nm, source=f"{nominal.source} (this seed's engine)")
        self.engine = Engine(self.engine_map, idle_rpm=p.engine_idle_rpm, idle_offset_rpm=p.engine_idle_offset_rpm,
                             governor_droop_rpm=p.engine_governor_droop_rpm, friction_nm=p.engine_friction_nm,
                             friction_at_3600_rpm_nm=p.engine_friction_at_3600_rpm_nm,
                             firing_ripple_ratio=p.engine_firing_ripple_ratio, inertia_kg_m2=p.engine_inertia_kg_m2)
        labelled = load_sim_tune(p.cvt_tune_path)
        # the parts on the rig are not their labels (--sim-tune-deviation); the host only has the labels
        self.tune_true, self.world = parts_on_the_rig(labelled, p, seed, self.world)
        tune = self.tune_true
        self.cvt = CVT(ratio_low=p.cvt_ratio_low, ratio_high=p.cvt_ratio_high,
                       primary_radius_max_m=p.cvt_primary_radius_max_m,
                       sheave_half_angle_deg=p.cvt_sheave_half_angle_deg,
                       flyweight_coeff_kg_m=p.cvt_flyweight_coeff_kg_m,
                       primary_spring_full_shift_n=p.cvt_primary_spring_full_shift_n,
                       primary_spring_rate_n_per_m=p.cvt_primary_spring_rate_n_per_m,
                       secondary_spring_preload_n=p.cvt_secondary_spring_preload_n,
                       secondary_spring_rate_n_per_m=p.cvt_secondary_spring_rate_n_per_m,
                       helix_gain_n_per_nm=p.cvt_helix_gain_n_per_nm,
                       shift_time_constant_s=p.cvt_shift_time_constant_s, tune=tune,
                       engage_start_rpm=p.cvt_engage_start_rpm,
                       engage_full_rpm=p.cvt_engage_full_rpm, clutch_capacity_nm=p.cvt_clutch_capacity_nm,
                       slip_base_frac=p.cvt_slip_base_frac, slip_per_20nm_frac=p.cvt_slip_per_20nm_frac,
                       loss_frac_min=p.cvt_loss_frac_min, loss_frac_high_ratio=p.cvt_loss_frac_high_ratio,
                       loss_frac_low_ratio=p.cvt_loss_frac_low_ratio, ratio_best_eff=p.cvt_ratio_best_eff,
                       bending_drag_nm=p.cvt_bending_drag_nm,
                       # the belt's thrust ratio needs its geometry: a tune-less closed-form CVT has none
                       belt_friction_coefficient=p.cvt_belt_friction_coefficient if tune is not None else None,
                       belt_thrust_model=p.cvt_belt_thrust_model,
                       flyweight_radius_offset_m=p.cvt_flyweight_radius_offset_m,
                       **belt_tables_for(p, labelled))  # (labelled: see dyno.sim.tune_deviation)
        friction = attach_friction(self.cvt, p, seed)  # this world's CVT friction (dyno.sim.cvt_friction)
        if p.cvt_engagement_model not in ("clamp", "smoothstep"):
            raise ValueError(f"cvt_engagement_model: 'clamp' or 'smoothstep', got {p.cvt_engagement_model!r}")
        self.engagement = None
        if p.cvt_engagement_model == "clamp":
            self.engagement = Engagement(self.cvt, friction_coefficient=friction.clutch_friction_coefficient,
                                         radius_m=clamp_radius_m(p, self.cvt),
                                         half_angle_deg=self.cvt.tune.drive.sheave_half_angle_deg
                                         if self.cvt.tune is not None else p.cvt_sheave_half_angle_deg,
                                         max_torque_nm=p.cvt_clutch_capacity_nm)
        self.driveline = Driveline(p)  # between the CVT and the gauge: driven_loss_nm, driveline_loss_*
        self.driveline_loss_nm = self.driveline.loss_nm
        self.brake = Brake(actuator_speed_mm_s=p.actuator_speed_mm_s, actuator_travel_mm=p.actuator_travel_mm,
                           free_travel_mm=p.brake_free_travel_mm, spring_rate_n_per_mm=p.brake_spring_rate_n_per_mm,
                           master_cylinder_bore_mm=p.master_cylinder_bore_mm,
                           caliper_piston_bore_mm=p.caliper_piston_bore_mm, pad_radius_m=p.brake_pad_radius_m,
                           mu_cold=p.brake_mu_cold, mu_fade_per_c=p.brake_mu_fade_per_c,
                           mu_floor_frac=p.brake_mu_floor_frac, residual_drag_nm=p.brake_residual_drag_nm,
                           rotor_heat_capacity_j_per_k=p.rotor_heat_capacity_j_per_k,
                           rotor_cooling_w_per_k=p.rotor_cooling_w_per_k,
                           rotor_cooling_w_per_k_per_rad_s=p.rotor_cooling_w_per_k_per_rad_s,
                           ambient_c=p.ambient_temp_c)
        self.kill = KillChain()
        self.pads = PadsRecord(self.brake.a0_mm, self.brake.a_max_mm)

        # Independent random streams, so that e.g. changing the bounce
        # probability does not change the ADC noise sequence.
        ss = np.random.SeedSequence(seed)
        s_noise, s_bounce, s_err, s_phase = ss.spawn(4)
        rng_phase = np.random.default_rng(s_phase)

        self.throttle_frac = 0.0  # inputs
        self.actuator_dir = 0
        self.relay_dir = -1                 # at rest: release
        self._relay_goal = -1
        self._relay_made_s = -math.inf      # when the contacts made on the goal's side
        self.brake_hold_relay = False       # K3 fitted (rig.toml actuator.brake_hold_relay): see _substep
        # fault knobs
        self.stuck_hall: set[str] = set()
        self.extra_rotor_heat_c_per_s = 0.0  # drill overtemp: a dragging pad heats the rotor while the engine runs
        self.governor_failed = False         # drill overspeed: throttle stuck wide open, governor gone

        g = p.gear_ratio_brake_per_secondary
        self._g = g
        self._j_e = p.engine_inertia_kg_m2
        self._j_s = p.secondary_inertia_kg_m2 + p.brake_shaft_inertia_kg_m2 * g * g
        # hot-loop constants
        self._stall_rpm = p.engine_stall_rpm
        self._j_rotor_g = p.brake_shaft_inertia_kg_m2 * g
        self._rotor_limit_c = p.rotor_temp_limit_c

        # state
        self.t_s = 0.0
        self._running = False
        self._th_e = 0.0
        self._w_e = 0.0
        self._th_s = float(rng_phase.uniform(0.0, TWO_PI))
        self._w_s = 0.0
        self._x = self.cvt.x_min
        self._ratio_geo = self.cvt.ratio_of_travel(self._x)
        self._slip = p.cvt_slip_base_frac
        self._locked = False
        self._cap = 0.0
        self._act_mm = self.pads.start(p.brake_start_mm)
        self._rotor_c = p.ambient_temp_c
        self._thermo_c = p.ambient_temp_c
        tau = p.thermometer_time_constant_s
        self._thermo_alpha = 1.0 - math.exp(-p.max_substep_s / tau) if tau > 0 else 1.0
        self._t_e = 0.0
        self._t_p = 0.0
        self._t_s = 0.0
        self._t_gauge = 0.0
        self._t_brake_cap = self.brake.torque_capacity_nm(self._act_mm, self._rotor_c)
        # (rng_phase: the secondary's angle above, then the signals' phases)
        self.signals = SensorSignals(p, np.random.default_rng(s_noise), np.random.default_rng(s_bounce),
                                     np.random.default_rng(s_err), rng_phase, self._th_s)
        self.input_cell = CradleLoadCell(p, seed, self.world, self.engine)  # the engine cradle's load cell
        self._buffer: list[SensorEvent] = []    # events computed ahead of the caller's time
        self._h = p.max_substep_s
        self._cell_index = 0
        self._cell_end_s = 0.0                  # physics state is at this time
        self._cell_start_s = 0.0
        self._w_e_start = 0.0
        self._w_s_start = 0.0

    # ------------------------------------------------------------ inputs
    def start_engine(self) -> None:
        """Operator pull-start: if enabled and stopped, the engine fires and runs up to idle."""
        if not self.magneto_fires or self._running:
            return
        self._running = True
        self._w_e = max(self._w_e, self.params.engine_start_rpm * RAD_S_PER_RPM)
        if self._locked:
            self._w_s = self._kin_ratio() * self._w_e

    @property
    def rotor_temp_c(self) -> float:
        """Brake rotor temperature (for the emulated MLX90614)."""
        return self._rotor_c

    @property
    def thermometer_c(self) -> float:
        """What the rotor thermometer's sensing element sees now (lagged, before noise)."""
        return self._thermo_c

    @property
    def actuator_mm(self) -> float:
        return self._act_mm

    @property
    def pads_off(self) -> bool:
        """The pads are off the rotor: the actuator is inside the brake's free travel (no pushrod force)."""
        return self._act_mm <= self.brake.a0_mm

    @property
    def engine_running(self) -> bool:
        return self._running

    def engine_cut(self, after_s: float = 0.0) -> tuple[float, str] | None:
        """(true time, by whom) of the first opening of the kill chain at or after ``after_s``
        (:meth:`dyno.sim.kill_chain.KillChain.engine_cut`)."""
        return self.kill.engine_cut(after_s)

    def ignition_step(self, t0: float) -> None:
        """The chain recorded at ``t0`` and the engine firing or not: no spark stops it; a spark back while the
        crank still turns above its stall speed re-fires it, as a magneto engine does (the 100 ms kill-path
        probe at idle, issue 49)."""
        self.kill.note(t0, self._act_mm)
        if not self.kill.magneto_fires:
            self._running = False
        elif not self._running and self._w_e * 30.0 / math.pi > self._stall_rpm:
            self._running = True

    def _kin_ratio(self) -> float:
        return (1.0 - self._slip) / self._ratio_geo

    # ------------------------------------------------------------ stepping
    def step(self, dt_s: float) -> list[SensorEvent]:
        """Advance by ``dt_s``; return the sensor events in ``(t, t + dt]``, in time order.

        The physics runs on a fixed grid of cells of ``max_substep_s``
        (computed ahead as far as needed, events buffered until their time),
        so the result does not depend on how the caller slices time: many
        tiny steps cost no more than one long one, and a seed gives the same
        rig whatever the host's polling pattern.  Inputs (throttle, kill,
        actuator, faults) set between calls act from the next cell boundary,
        i.e. with at most one cell (4 ms by default) of latency.
        """
        if not dt_s >= 0.0:
            raise ValueError("dt_s must be >= 0")
        t_end = self.t_s + dt_s
        buf = self._buffer
        h = self._h
        while self._cell_end_s < t_end:
            t0 = self._cell_end_s
            self._cell_index += 1
            t1 = self._cell_index * h
            self._substep(t0, h, buf)   # nominal h: keeps the filter's discretisation cached
            self._cell_end_s = t1
        self.t_s = t_end
        if not buf:
            return []
        buf.sort(key=attrgetter("t_s"))
        stuck = self.stuck_hall
        out: list[SensorEvent] = []
        k = 0
        for ev in buf:
            if ev.t_s > t_end:
                break
            k += 1
            if stuck and ev.channel in stuck:
                continue        # a stuck sensor gives no edges (nor the bounce of an earlier one)
            out.append(ev)
        del buf[:k]
        return out

    def events_ahead(self, until_s: float) -> list[SensorEvent]:
        """The sensor events in ``(t, until_s]`` without advancing ``t``: their cells are computed now, so inputs
        set before ``until_s`` act from the cell after (a firmware in the loop needs the edges that fall during
        a bus transfer before the transfer runs)."""
        h = self._h
        while self._cell_end_s < until_s:
            self._cell_index += 1
            self._substep(self._cell_end_s, h, self._buffer)
            self._cell_end_s = self._cell_index * h
        stuck = self.stuck_hall
        return sorted((ev for ev in self._buffer if self.t_s < ev.t_s <= until_s
                       and not (stuck and ev.channel in stuck)), key=attrgetter("t_s"))

    def _substep(self, t0: float, h: float, events: list[SensorEvent]) -> None:
        p = self.params
        cvt = self.cvt
        eng = self.engine
        brk = self.brake
        g = self._g
        j_e = self._j_e
        j_s = self._j_s
        self.ignition_step(t0)

        # --- actuator and brake capacity (inputs act from the start of the step)
        if self.actuator_dir:  # powered: the coil is wherever the command points
            self.relay_dir = self.actuator_dir
        if self.relay_dir != self._relay_goal:  # the coil changed: contacts in transit from this cell
            self._relay_goal = self.relay_dir
            self._relay_made_s = t0 + p.relay_transfer_s
        a_before = self._act_mm
        if self.brake_hold_relay and not self.ignition_on:
            # K3 (hardware/README.md) off with the kill relay: its NC contacts drive the actuator in release
            # to its end stop, the driver cut off
            self._act_mm = brk.move_actuator_mm(self._act_mm, -1, h)
        elif self.actuator_dir:
            run_s = t0 + h - self._relay_made_s  # powered time with the contacts made, in this cell
            if run_s > 0.0:
                self._act_mm = brk.move_actuator_mm(self._act_mm, self._relay_goal, h if run_s > h else run_s)
        self.pads.note(t0, h, a_before, self._act_mm)
        t_brake_cap = brk.torque_capacity_nm(self._act_mm, self._rotor_c)   # brake shaft
        fric = p.cvt_secondary_friction_torque_nm + p.world_driveline_loss_frac * max(self._t_s, 0.0)  # after the helix
        if self.driveline.on:  # bearings, mesh, windage; the chain's load share (on the last cell's belt torque)
            fric += self.driveline.between_nm(self._w_s, self._t_s)
        t_load_cap = t_brake_cap * g + fric                                 # referred to the secondary

        w_e0 = self._w_e
        w_s0 = self._w_s
        rpm_e = w_e0 * RPM_PER_RAD_S
        running = self._running
        if self.governor_failed:
            t_e = eng.torque_nm(rpm_e, 1.0, running, governed=False)
        else:
            t_e = eng.torque_nm(rpm_e, self.throttle_frac, running)

        # --- shift: quasi-static balance + first-order lag (exact exponential)
        self._x = cvt.shift(self._x, rpm_e, self._t_s, h, self._t_p)
        i = cvt.ratio_of_travel(self._x)
        self._ratio_geo = i
        eps, self._slip = cvt.losses(i, self._t_p)
        eta_m = 1.0 - eps
        t_d = cvt.drag_nm(i)
        k = (1.0 - self._slip) / i
        cap = self.engagement.capacity_nm(rpm_e, self._x) if self.engagement else cvt.clutch_capacity_nm_at(rpm_e)
        self._cap = cap

        locked = self._locked
        if locked:
            # Ratio changed since the last step: belt impulse keeps the two
            # speeds consistent, conserving i J_e w_e + J_s w_s.
            w_e0 = (i * j_e * w_e0 + j_s * w_s0) / (j_s * k + i * j_e)
            w_s0 = k * w_e0
            acc, t_p = self._locked_accel(t_e, i, k, eta_m, t_d, t_load_cap)
            if abs(t_p) > cap or not running and w_e0 <= 0.0:
                locked = False
        if locked:
            w_e1 = w_e0 + acc * h
            if w_e1 < 0.0:
                w_e1 = 0.0
            w_s1 = k * w_e1
            t_s = cvt.secondary_torque_nm(t_p, i, eta_m, t_d)
            acc_s = (w_s1 - w_s0) / h
            t_brake_applied = t_brake_cap if w_s1 > 0.0 else after_drag(t_s, fric) / g
        else:
            # Belt slipping (or open): torque limited by the engagement capacity.
            v_rel = k * w_e0 - w_s0
            if cap > 0.0 and v_rel != 0.0:
                t_p = cap if v_rel > 0.0 else -cap
            else:
                t_p = 0.0
            t_s = i * eta_m * t_p if t_p >= 0.0 else i * t_p / eta_m
            w_e1 = w_e0 + h * (t_e - t_p) / j_e
            if w_e1 < 0.0:
                w_e1 = 0.0
            # Karnopp stick/slip for the brake on the secondary side.
            if w_s0 <= 0.0 and abs(t_s) <= t_load_cap:
                w_s1 = 0.0
                t_brake_applied = after_drag(t_s, fric) / g
            else:
                w_s1 = w_s0 + h * (t_s - t_load_cap) / j_s
                t_brake_applied = t_brake_cap
                if w_s1 <= 0.0:
                    w_s1 = 0.0
            acc_s = (w_s1 - w_s0) / h
            # Lock when the slip speed crosses zero and the locked torque fits.
            v_rel1 = k * w_e1 - w_s1
            if cap > 0.0 and (v_rel > 0.0) != (v_rel1 > 0.0) or (cap > 0.0 and v_rel == 0.0 and w_e1 > 0.0):
                acc_l, t_p_l = self._locked_accel(t_e, i, k, eta_m, t_d, t_load_cap)
                if abs(t_p_l) <= cap:
                    w_e1 = (i * j_e * w_e1 + j_s * w_s1) / (j_s * k + i * j_e)
                    w_s1 = k * w_e1
                    locked = True
                    t_p = t_p_l
                    t_s = cvt.secondary_torque_nm(t_p, i, eta_m, t_d)
                    acc_s = (w_s1 - w_s0) / h
        self._locked = locked

        if running and w_e1 * RPM_PER_RAD_S < self._stall_rpm and w_e1 < w_e0:
            self._running = False   # stalled

        self._cell_start_s = t0
        self._w_e_start = w_e0
        self._w_s_start = w_s0

        # --- angles (trapezoid = exact for the constant acceleration of the step)
        th_e0 = self._th_e
        th_s0 = self._th_s
        a_e = (w_e1 - w_e0) / h
        a_s = (w_s1 - w_s0) / h
        th_e1 = th_e0 + 0.5 * (w_e0 + w_e1) * h
        th_s1 = th_s0 + 0.5 * (w_s0 + w_s1) * h
        self._th_e = th_e1
        self._th_s = th_s1
        self._w_e = w_e1
        self._w_s = w_s1
        self._t_e = t_e
        self._t_p = t_p
        self._t_s = t_s
        self._t_brake_cap = t_brake_cap

        # --- torque in the instrumented brake shaft: brake + rotor inertia
        t_gauge = t_brake_applied + self._j_rotor_g * acc_s
        self._t_gauge = t_gauge

        # --- rotor heat (exact relaxation over the step)
        w_b = 0.5 * (w_s0 + w_s1) * g
        p_brake = t_brake_cap * w_b if w_b > 0.0 else 0.0
        if self.extra_rotor_heat_c_per_s and self.ignition_on:
            p_brake += self.extra_rotor_heat_c_per_s * p.rotor_heat_capacity_j_per_k
        self._rotor_c = min(brk.rotor_temp_after_c(self._rotor_c, p_brake, w_b, h), self._rotor_limit_c)
        # the thermometer sees the rotor through a first-order lag (exact for the held step)
        self._thermo_c += (self._rotor_c - self._thermo_c) * self._thermo_alpha

        # --- Hall edges
        sig = self.signals
        if sig.primary_edge_near(th_e1):
            amp = eng.firing_angle_amplitude_rad(w_e1, t_e, rpm_e) if running else 0.0
            sig.primary_edges(t0, h, th_e0, w_e0, a_e, th_e1, amp, events)
        sig.secondary_edges(t0, h, th_s0, w_s0, a_s, th_s1, events)

        # --- lock-in filter (exact ZOH) and ADC conversions
        sig.adc_events(t0, h, t_gauge, self._rotor_c, th_e0, w_e0, a_e, th_s0, w_s0, a_s, events)
        if self.input_cell.fitted:
            # the cradle's reaction R = T_p + J_e a_e (= T_e while the crank turns; 0 at rest, where the
            # engine's friction holds nothing)
            self.input_cell.cell_events(t0, h, th_e0, w_e0, a_e, t_p + j_e * a_e, t_e, rpm_e, running, events)

    # ------------------------------------------------------------ truth
    def truth(self) -> Truth:
        """True state at the caller's time ``t_s``.

        Speeds are interpolated within the physics cell (they vary linearly
        there); torques, powers and temperatures are the cell's values.
        """
        span = self._cell_end_s - self._cell_start_s
        f = (self.t_s - self._cell_start_s) / span if span > 0.0 else 1.0
        f = 0.0 if f < 0.0 else (1.0 if f > 1.0 else f)
        w_e = self._w_e_start + f * (self._w_e - self._w_e_start)
        w_s = self._w_s_start + f * (self._w_s - self._w_s_start)
        p_in = self._t_p * w_e
        p_out = self._t_s * w_s
        eff = p_out / p_in if p_in > 1e-9 and p_out > 0.0 else 0.0
        speed_ratio = w_e / w_s if w_s > 1e-9 else 0.0
        return Truth(
            t_s=self.t_s,
            rpm_primary=w_e * RPM_PER_RAD_S,
            rpm_secondary=w_s * RPM_PER_RAD_S,
            ratio=speed_ratio,
            torque_engine_nm=self._t_e,
            torque_primary_nm=self._t_p,
            torque_secondary_nm=self._t_s,
            torque_brake_shaft_nm=self._t_gauge,
            power_in_w=p_in,
            power_out_w=p_out,
            efficiency=eff,
            rotor_temp_c=self._rotor_c,
            actuator_mm=self._act_mm,
            engine_running=self._running,
            ratio_geometric=self._ratio_geo,
            shift_travel_frac=self._x,
            power_engine_w=self._t_e * w_e,
            power_loss_w=p_in - p_out,
            brake_mu=self.brake.mu(self._rotor_c),
            brake_torque_capacity_nm=self._t_brake_cap,
            clutch_locked=self._locked,
            clutch_capacity_nm=self._cap,
            belt_slip=self._slip,
            driveline_loss_nm=self.driveline_loss_nm(w_s, self._t_s) if w_s > 0.0 else 0.0,
        )

    def _locked_accel(self, t_e, i, k, eta_m, t_d, t_load):
        """Crank acceleration and belt input torque with the belt gripping."""
        j_e = self._j_e
        j_s = self._j_s
        acc = (i * eta_m * t_e - i * t_d - t_load) / (j_s * k + i * eta_m * j_e)
        t_p = t_e - j_e * acc
        if t_p < 0.0:
            # reverse power flow (engine braking): losses the other way
            acc = (i * t_e / eta_m - i * t_d - t_load) / (j_s * k + i * j_e / eta_m)
            t_p = t_e - j_e * acc
        return acc, t_p

