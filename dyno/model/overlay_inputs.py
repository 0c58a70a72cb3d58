"""Measured points as belt-model operating points: what the overlay predicts at (:mod:`dyno.model.overlay`).

Used by the live screen, the web view and the report alike (the faces call it; it calls no face).
"""

from __future__ import annotations


def overlay_inputs(points, tune=None, *, tier: str = "closed_form") -> list:
    """(secondary rpm, operating point) of each valid point, for :func:`dyno.model.overlay.predict_overlay`.

    The operating point is the slip-consistent inverse's (:mod:`dyno.model.inverse`): the geometric
    ratio and clamp that reproduce the measured speed ratio at the measured primary speed and torque,
    with ``tune`` (a :class:`~dyno.tuning.tune.Tune` or a TOML path, e.g. the run's ``tune.toml``)
    giving the clamp (flyweights minus spring at the measured rpm).  Without a tune: the thesis's
    Table 6.1 drive at 100 N of slack tension.  The primary torque is the engine-map torque the
    efficiency was computed with (power_in / omega_primary); the secondary rpm places the
    prediction on the efficiency plot.  Points whose inverse finds no steady belt (gross slip at
    the tune's clamp, spring holding the sheave open) are left out.  ``tier``: the inverse's slip,
    ``closed_form`` (microseconds per point) or ``full`` (seconds per point).
    """
    from dyno.model.inverse import invert_points

    from dyno.tuning.tune import Tune, load_tune

    if tune is not None and not isinstance(tune, Tune):
        tune = load_tune(tune)
    return [(rs, res.operating_point()) for rs, res in invert_points(points, tune, tier=tier) if res.ok]
