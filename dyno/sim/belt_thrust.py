r"""The simulated belt's thrust ratio and creep at a state of the CVT (:meth:`dyno.sim.cvt.CVT.belt_state`).

A loaded V-belt does not pass the primary's clamp to the secondary unchanged: the primary clamp
:math:`F_p` sets its tensions, and the belt then *requires* a secondary thrust
:math:`F_{s,belt} = \kappa F_p`; the CVT shifts until the secondary's springs and helix give it.

* ``"full"`` (the simulated rig's default): :math:`\kappa` and the creep of the project's full belt model
  (:mod:`dyno.model`: the boundary-value problem with seating and radial friction), read from the belt table's
  cells (:mod:`dyno.sim.belt_table`, solved once per tune at its clamp at ``TABLE_RPM``).  Between cells,
  and at another clamp, the cell is read at the torque that puts the same load on the clamp,
  :math:`T_{cell} = T_p\,F_{p,cell}(i)/F_p` (the belt's forces scale with the clamp while centrifugal
  tension is small: at 3,000 rpm it is ~2 % of the slack side's).  Where the full model finds gross slip
  (the clamp cannot carry the torque: the clutch slips, and :mod:`dyno.sim.driven` limits what passes) the
  belt keeps the thrust ratio of the highest torque it carries at that ratio.
* ``"capstan"``: Gerbert's V-belt at a stated friction (``--sim-belt-thrust F``);
* ``"closed_form"``: Sorge & Cammalleri's eqs. 17–18 — the model :mod:`dyno.tuning.fit` fits (circular:
  a control only).
"""

from __future__ import annotations


def belt_state(cvt, x: float, rpm_primary: float, torque_primary_nm: float) -> tuple:
    """(creep slip or None, thrust ratio kappa or None = keep the current one) at this state; pure."""
    f_p = cvt.primary_force_n(rpm_primary, x)
    if f_p <= 0.0 or rpm_primary <= 0.0:
        return None, None  # no clamp (clutch open): the loss model's slip; kappa does not enter
    if not torque_primary_nm > 1e-6:
        return 0.0, None  # no torque, no tension difference, no creep; kappa kept
    ratio = cvt.ratio_of_travel(x)
    if cvt.belt_params == "full":
        return _full(cvt.thrust_table, ratio, f_p, torque_primary_nm)
    return _tiers(cvt, ratio, rpm_primary, f_p, torque_primary_nm)


def _full(table, ratio: float, f_p: float, torque_primary_nm: float) -> tuple:
    clamp = table.clamp_at(ratio)
    t_cell = torque_primary_nm * clamp / f_p if clamp == clamp else torque_primary_nm  # (NaN: slack tension)
    kappa = table.lookup_kappa(ratio, t_cell)
    if kappa is None:
        return None, None  # (a table without a single converged cell: the running thrust ratio is kept)
    eta = table.lookup(ratio, t_cell)
    # creep: the full model's speed loss where the cell's efficiencies are in range (else the loss model's)
    return (None if eta is None else max(0.0, 1.0 - eta[1])), kappa


def _tiers(cvt, ratio: float, rpm_primary: float, f_p: float, torque_primary_nm: float) -> tuple:
    from dyno.errors import MODEL_FAILURES, ConfigError
    from dyno.model.closed_form import closed_form_point
    from dyno.model.params import OperatingPoint

    op = OperatingPoint(ratio=ratio, primary_speed_rpm=rpm_primary,
                        primary_torque_nm=max(torque_primary_nm, 0.0), slack_tension_n=None,
                        primary_axial_force_n=f_p)
    try:
        res = closed_form_point(cvt.creep_params, op)
    except (ConfigError, *MODEL_FAILURES):
        # The clamp cannot carry the torque: the secondary wins (as in
        # dyno.tuning.shift_curve.Solver.residual_n), the CVT downshifts.
        return None, 0.0
    creep = 1.0 - res.efficiency_speed
    if cvt.belt_params is None:
        return creep, None
    if cvt.belt_thrust_model == "capstan":
        from dyno.model.capstan import capstan_point

        try:
            cap = capstan_point(cvt.belt_params, op)
        except (ConfigError, ValueError, *MODEL_FAILURES):
            return creep, 0.0
        return creep, (0.0 if cap.gross_slip else cap.axial_force_secondary_n / cap.axial_force_primary_n)
    return creep, res.axial_force_secondary_n / f_p
