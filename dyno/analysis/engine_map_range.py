"""An engine map's range faults: a speed outside the map, a power it never makes, a throttle without a curve.

Each names the map's range, so a point outside it says why it has no efficiency (torque and power stay).
"""

from __future__ import annotations

import math

from dyno.errors import DynoError


class OutOfMapRange(DynoError, ValueError):
    """An engine speed lies outside the engine map; extrapolating would be a guess."""

    def __init__(self, rpm, rpm_min: float, rpm_max: float, source: str = ""):
        self.rpm = rpm
        self.rpm_min = rpm_min
        self.rpm_max = rpm_max
        where = f" ({source})" if source else ""
        super().__init__(f"engine speed {rpm} rpm is outside the engine map{where} range "
                         f"[{rpm_min:g}, {rpm_max:g}] rpm; refusing to extrapolate")


class NoMapPower(OutOfMapRange):
    """The map gives no power at this speed (e.g. governor cut-off): no efficiency.

    A subclass of :class:`OutOfMapRange` because it means the same thing to a
    caller: this engine speed is outside the part of the map that can serve
    as an efficiency denominator.
    """

    def __init__(self, rpm: float, power_w: float, rpm_min: float, rpm_max: float, source: str = ""):
        ValueError.__init__(self)  # skip OutOfMapRange's message, keep its attributes
        self.rpm, self.rpm_min, self.rpm_max, self.power_w = rpm, rpm_min, rpm_max, power_w
        where = f" ({source})" if source else ""
        self.args = (f"engine map{where} gives {power_w:g} W at {rpm:g} rpm (governor cut-off?); "
                     f"efficiency is undefined there",)


#: a point's throttle matches a map curve's within this (fractions of full throttle): the servo's
#: setting is commanded, so a point at 0.6 matches the 0.6 curve exactly; 0.005 absorbs the 3-4
#: decimals a CSV writer may round to, and nothing more (see :meth:`EngineMap.at_throttle`)
THROTTLE_TOL = 0.005


class NoThrottleCurve(OutOfMapRange):
    """The map has no curve at a point's throttle: no efficiency denominator (torque and power stay)."""

    def __init__(self, throttle_frac: float, throttles, source: str = ""):
        ValueError.__init__(self)
        self.throttle_frac = throttle_frac
        self.throttles = tuple(throttles)
        self.rpm, self.rpm_min, self.rpm_max = math.nan, math.nan, math.nan
        self.source = source  # (not in the message: a replay reads the run's copy of the same map)
        have = ", ".join(f"{t:.2f}" for t in self.throttles)
        self.args = (f"no engine-map curve at throttle {throttle_frac:.2f} (the map has throttle {have}): "
                     f"efficiency undefined without a curve at the point's throttle",)
