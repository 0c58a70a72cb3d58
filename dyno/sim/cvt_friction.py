r"""The simulated CVT's friction: the clutch's flank friction and the shift's Coulomb friction (a hysteresis).

The host's models (the advisor's figures, the shift-curve model) are frictionless balances with the thesis's
flank friction 0.4.  A real CVT is not: each world (rig) here has its own, drawn once per world seed from
this module's own random stream (``0x26``; the engine, sensor and day use ``0x24``, the parts ``0x25``):

* **clutch flank friction** :math:`\mu_c` (:mod:`dyno.sim.driven`'s engagement rule): the belt's
  rubber (CR/HNBR compound with aramid cords) slipping on machined aluminium sheaves, dry: 0.30-0.45
  (V-belt handbooks state 0.3-0.5 for rubber on metal; Gerbert's V-belt analyses use 0.3-0.4; the thesis
  takes 0.4).  Drawn uniform on ``CLUTCH_MU_RANGE``.
* **primary ramps and rollers** :math:`h_p`: the flyweights' rollers turn on bushed pins and the moving
  sheave slides on its post: a fraction 0.005-0.015 of the flyweights' axial force :math:`C(x) n^2` is lost
  to friction whenever the sheave moves (``RAMP_FRAC_RANGE``).
* **secondary helix** :math:`h_s`: the helix buttons (PTFE-filled nylon on hard-anodised aluminium) slide
  on the ramp: a fraction 0.01-0.03 of the helix's axial force :math:`B(x) T_s` (``HELIX_FRAC_RANGE``).
* **sheave bushings** :math:`F_{sh}`: the two moving sheaves on their posts, 2-8 N together
  (``SHEAVE_N_RANGE``), load-independent.

The shift frictions' ranges are bounded by the 2019 logs (run2 and run3, against the 75 rpm limit of
bench/bench_fidelity.py): the steady points of a loading run sit on the back-shift edge of the dead band.
(Firing-pulse vibration dithers part of a real CVT's static friction away in steady running.)

Friction opposes the sheaves' motion, so the shift balance has a dead band
:math:`|F_p - F_s| \le F_f` in which the sheaves stay where they are, with

.. math:: F_f(n, T_s, x) = \kappa\,h_p\,C(x)\,n^2 + h_s\,B(x)\max(T_s, 0) + F_{sh}

(:math:`\kappa` the belt's thrust ratio: the ramp loss is on the primary's side of the belt).  The
up-shift starts only when :math:`F_p - F_s > F_f` and the back-shift when :math:`F_p - F_s < -F_f`: the
engine speed of an up-shift is higher than the frictionless balance, that of a back-shift lower.  The
engagement (the sheave closing on the belt while the engine speeds up) sees the primary clamp less the
ramp loss and the bushing: :math:`(1 - h_p) C n^2 - S_p - F_{sh}/2`.

Every ``*_true`` figure of the engagement plan (:func:`dyno.sim.driven.characterisation_truth`) is the
up-shift's (engine speed rising): ``engagement_rpm_true`` with the closing clamp above,
``shift_out_rpm_true`` where :math:`F_p - F_s = F_f` at the low stop.

``ideal=True`` rigs (``--sim-ideal``) take each range's centre.  A number set in
:class:`~dyno.sim.rig_params.RigParams` (``cvt_clutch_friction_coefficient``, ``cvt_ramp_friction_frac``,
``cvt_helix_friction_frac``, ``cvt_sheave_friction_n``) replaces its draw (0 switches a friction off).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

CLUTCH_MU_RANGE = (0.30, 0.45)
RAMP_FRAC_RANGE = (0.005, 0.015)
HELIX_FRAC_RANGE = (0.01, 0.03)
SHEAVE_N_RANGE = (2.0, 8.0)
_STREAM = 0x26


@dataclass(frozen=True)
class CvtFriction:
    """One world's CVT friction (the sim's truth; recorded in the characterisation truth)."""

    clutch_friction_coefficient: float
    ramp_friction_frac: float
    helix_friction_frac: float
    sheave_friction_n: float

    def to_dict(self) -> dict:
        return asdict(self)


def draw_friction(p, seed: int) -> CvtFriction:
    """This world's friction from ``RigParams`` ``p`` (a set value wins over its draw; ideal: the centres)."""
    world_seed = int(seed if p.world_seed is None else p.world_seed)
    rng = np.random.default_rng(np.random.SeedSequence([world_seed, _STREAM]))
    ranges = (CLUTCH_MU_RANGE, RAMP_FRAC_RANGE, HELIX_FRAC_RANGE, SHEAVE_N_RANGE)
    # always draw all four, so that a value given for one does not move the others
    drawn = [float(rng.uniform(lo, hi)) for lo, hi in ranges]
    if getattr(p, "ideal", False):
        drawn = [0.5 * (lo + hi) for lo, hi in ranges]
    given = (p.cvt_clutch_friction_coefficient, p.cvt_ramp_friction_frac, p.cvt_helix_friction_frac,
             p.cvt_sheave_friction_n)
    vals = [d if g is None else float(g) for d, g in zip(drawn, given)]
    if not (0.0 < vals[0] <= 1.5) or not all(0.0 <= v < 1.0 for v in vals[1:3]) or vals[3] < 0.0:
        raise ValueError(f"CVT friction out of range: mu_c in (0, 1.5], ramp/helix fractions in [0, 1), "
                         f"sheave friction >= 0 N, got {vals}")
    return CvtFriction(*vals)


def attach_friction(cvt, p, seed: int) -> CvtFriction:
    """Draw this world's friction and attach the shift's to ``cvt`` (a tune-less closed-form CVT: the clutch
    friction alone, its shift stays frictionless)."""
    fr = draw_friction(p, seed)
    cvt.friction = fr if cvt.tune is not None else None
    return fr


def friction_n(cvt, rpm_primary: float, torque_secondary_nm: float, x: float) -> float:
    """The dead band ``F_f`` (N) of the shift balance at this state (module docstring)."""
    fr = cvt.friction
    if fr is None:
        return 0.0
    cc, bb = cvt.shift_coefficients(x)
    t = torque_secondary_nm if torque_secondary_nm > 0.0 else 0.0
    return cvt.thrust_ratio * fr.ramp_friction_frac * cc * rpm_primary * rpm_primary + fr.helix_friction_frac * bb * t \
        + fr.sheave_friction_n


def closing_clamp_n(cvt, rpm_primary: float, x: float) -> float:
    """The primary's clamp as the sheave closes on the belt (engine speeding up): ramp loss and bushing off."""
    f = cvt.primary_force_n(rpm_primary, x)
    fr = cvt.friction
    if fr is None:
        return f
    c = cvt.shift_coefficients(x)[0]
    return f - fr.ramp_friction_frac * c * rpm_primary * rpm_primary - 0.5 * fr.sheave_friction_n
