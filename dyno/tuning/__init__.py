"""CVT tuning and design tools (issue 7).

* :mod:`dyno.tuning.tune` -- tune files (TOML) and their dataclasses;
* :mod:`dyno.tuning.actuators` -- primary flyweights/rollers and spring,
  secondary spring and helix with the eq. 11 torque split;
* :mod:`dyno.tuning.geometry` -- open-belt geometry;
* :mod:`dyno.tuning.shift_curve` -- predicted steady shift curve;
* :mod:`dyno.tuning.design` -- Arango & Munoz (2020) design method;
* :mod:`dyno.tuning.arcvt` -- AR-CVT actuation (van Kerkhoven 2006).

Submodules are imported explicitly; this package imports nothing heavy.
"""
