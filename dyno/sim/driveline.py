"""The simulated rig's driveline between the CVT and the torque gauge (``RigParams.driveline_loss_*``).

The secondary shaft's bearings and seal and the chain (or gear pair) to the brake shaft take, at the secondary,

.. math:: T_{dl}(\\omega_s, T_s) = a + b\\,\\omega_s + f\\,T_s

a drag (speed-dependent: bearings, seal, the chain's churn) and a share of the belt's output torque ``T_s``
(the chain's mesh loss), upstream of the gauge: the gauge reads the belt's output less it, while the truth's
efficiency stays the belt's (the CVT's) own.  The numbers and their basis: :mod:`dyno.sim.rig_params`.
A coast-down (the belt let go, no load) sees ``a + b w`` only; the load share no coast-down can see.
"""

from __future__ import annotations

import math

from dyno.sim.driven import parasitic_nm
from dyno.sim.engine import RAD_S_PER_RPM
from dyno.sim.rig_params import driveline_loss_of


class Driveline:
    """``loss_nm(omega_s, T_s)`` of the module docstring; ``on`` False when every coefficient is 0."""

    def __init__(self, params) -> None:
        # the driven-side parasitic loss a + b w + c w^2 (RigParams.driven_loss_nm, dyno.sim.driven; off by default)
        self.parasitic = tuple(float(v) for v in params.driven_loss_nm)
        if len(self.parasitic) != 3 or any(not math.isfinite(v) or v < 0 for v in self.parasitic):
            raise ValueError(f"driven_loss_nm: three finite coefficients >= 0, got {params.driven_loss_nm!r}")
        self.drag_nm, per_krpm, self.load_frac = driveline_loss_of(params)
        self.drag_nm_per_rad_s = per_krpm / (1000.0 * RAD_S_PER_RPM)
        if (any(not (math.isfinite(v) and v >= 0) for v in (self.drag_nm, self.drag_nm_per_rad_s, self.load_frac))
                or self.load_frac >= 1):
            raise ValueError("driveline_loss_*: finite and >= 0, the load fraction < 1")
        self.on = bool(self.drag_nm or self.drag_nm_per_rad_s or self.load_frac or any(self.parasitic))

    def loss_nm(self, omega_s_rad_s: float, torque_secondary_nm: float = 0.0) -> float:
        """The loss at the secondary: the drag at this speed plus the load share (none flows backwards here)."""
        w = omega_s_rad_s if omega_s_rad_s > 0.0 else 0.0
        t = torque_secondary_nm if torque_secondary_nm > 0.0 else 0.0
        return self.drag_nm + self.drag_nm_per_rad_s * w + self.load_frac * t

    def between_nm(self, omega_s_rad_s: float, torque_secondary_nm: float) -> float:
        """Everything between the CVT's output and the gauge: the parasitic loss and the driveline's."""
        return parasitic_nm(self.parasitic, omega_s_rad_s) + self.loss_nm(omega_s_rad_s, torque_secondary_nm)
