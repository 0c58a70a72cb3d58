"""The engine-side input torque channel in a run (issue 27): composition, split from :mod:`dyno.session.root`.

rig.toml ``[input_torque]`` declares the channel.  Then the simulated rig has it (its cradle load cell and
second converter, :mod:`dyno.sim.input_torque`), the reader asks the firmware for it at every boot
(docs/protocol.md), the run's ``meta.json`` keeps its calibration, and every point gets its measured input
power, its efficiency ``P_out / (T_in ω_p)`` with that path's ``efficiency_u95``, and the map's figure
beside it (:mod:`dyno.analysis.input_torque`).  Without the table nothing here runs.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path



def calibration_path(cfg) -> Path:
    """The channel's calibration history: as given (absolute or found from here), else the state directory's
    copy, else the shipped one (:mod:`dyno.session.calibration_files`)."""
    from dyno.session.calibration_files import calibration_in_force

    p = Path(cfg.calibration)
    if p.is_absolute() or p.exists():
        return p
    return calibration_in_force(p.name)


def load_input_channel(rig_cfg):
    """The declared channel (:class:`~dyno.analysis.input_torque.InputChannel`), or None."""
    cfg = getattr(rig_cfg, "input_torque", None)
    if cfg is None:
        return None
    from dyno.analysis.input_torque import load_channel
    from dyno.errors import ConfigError

    path = calibration_path(cfg)
    if not path.is_file():
        raise ConfigError(rig_cfg.path, "input_torque.calibration", f"a calibration history file (no {path})")
    return load_channel(cfg, path)


def sim_params_for(params, rig_cfg):
    """The simulated rig's parameters with the channel fitted when rig.toml declares it, and at its site
    (``[ambient] altitude_m``: where the rig stands is a fact of its world, not knowledge of the host's)."""
    site_m = getattr(getattr(rig_cfg, "ambient", None), "altitude_m", None)
    if getattr(rig_cfg, "input_torque", None) is None and site_m is None:
        return params
    from dyno.sim.rig_params import RigParams

    params = params if params is not None else RigParams()
    if site_m is not None and params.site_altitude_m is None:
        params = dataclasses.replace(params, site_altitude_m=float(site_m))
    if getattr(rig_cfg, "input_torque", None) is not None:
        params = dataclasses.replace(params, input_torque_fitted=True)
    return params


def input_meta(channel) -> dict:
    """``meta.json``'s ``input_torque`` (what a replay needs), or nothing without the channel."""
    if channel is None:
        return {}
    return {"input_torque": {"calibration": channel.calibration.to_dict(), "calibration_rel": channel.calibration_rel,
                             "bearing_loss_nm": channel.bearing_loss_nm,
                             "bearing_loss_u_nm": channel.bearing_loss_u_nm, "source": channel.source}}


def state_terms(uncertainty: dict, ambient, channel) -> None:
    """Complete ``uncertainty["u95_terms"]`` (dyno.analysis.u95_terms) once the day's air and the input
    channel are known: the air term, and with the channel its own terms."""
    from dyno.analysis import u95_terms

    terms = uncertainty.setdefault("u95_terms", [])
    terms.append(u95_terms.air_term(uncertainty.get("air_rel", 0.0), getattr(ambient, "source", None)))
    if "driveline_loss_max_frac" in uncertainty:
        terms.append(u95_terms.driveline_term(uncertainty["driveline_loss_max_frac"],
                                              uncertainty.get("driveline_drag_max_nm", 0.0)))
    if channel is not None:
        terms.extend(u95_terms.input_terms(channel))



class InputPointHook:
    """The input path added to every point (after the map's terms): a point hook of the controller.

    The first point tares the channel from GO's zero window, as the brake-side channel is
    (:meth:`dyno.control.controller.TestController.tare_input` keeps it for the live screen and the zero
    check); every point then gets ``input_point`` and its systematic terms.  ``controller_of()``: the controller
    the hook is given to (at its construction: called only when a point is recorded)."""

    def __init__(self, controller_of, channel, streams, uncertainty: dict) -> None:
        self._controller_of, self.channel, self.streams = controller_of, channel, streams
        self.uncertainty = uncertainty
        self.tared = False

    @property
    def controller(self):
        return self._controller_of()

    def __call__(self, point: dict, t0_s, t1_s) -> None:
        from dyno.analysis.input_torque import input_point, input_systematic, input_zero
        from dyno.analysis.systematic import calibration_rel_for, driveline_bound

        controller = self.controller
        if not self.tared:
            self.tared = True
            zb = getattr(controller, "zero_before", None) or {}
            if controller.tare is not None and "t_start_us" in zb:  # as the brake-side channel: from GO's zero
                zero = input_zero(self.streams, zb["t_start_us"], zb["t_end_us"], self.channel)
                self.channel = self.channel.with_zero(zero)
                controller.tare_input(self.channel)
                if self.channel.tare is not None:
                    controller.plan_context.log("tare_input", **self.channel.tare)
        point.update(input_point(self.streams, point, self.channel))
        rel_out = calibration_rel_for(self.uncertainty.get("torque_calibration_rel", 0.0), point, controller.tare)
        point.update(input_systematic(point, rel_out, self.channel, driveline_bound(point, self.uncertainty)))
