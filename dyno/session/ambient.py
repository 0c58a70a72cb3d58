"""The run's air: read from the rig's BME280, given (``--ambient``, ``rig.toml [ambient]``), or none.

Thin adapter between the pure :mod:`dyno.analysis.air` and the bus (:mod:`dyno.hw.bme280`, or the
simulated chip the simulated bus serves when ``rig.toml`` declares one).  The composition root reads
the air before the run starts (seconds before GO, while nothing else uses the bus) and after it ends;
the first reading takes the engine map to the run's day (SAE J1349), both are logged.
"""

from __future__ import annotations

from dyno.analysis.air import Ambient
from dyno.errors import ConfigError
from dyno.hw.bme280 import read_sensor  # one reading as an Ambient


def sim_bme280_address(rig_cfg) -> int | None:
    """Where the simulated rig plugs its BME280 chip (``SimRig(bme280_address=...)``): only when the rig file
    says one is fitted (None: none)."""
    return rig_cfg.ambient.address if rig_cfg.ambient.sensor == "bme280" else None


def ambient_sensor(rig_cfg, *, sim=None, hw=None):
    """The rig's BME280 driver (None when ``rig.toml`` declares none): the rig's, or one on the simulated bus
    (whose chip the simulated rig was built with, :func:`sim_bme280_address`)."""
    if rig_cfg.ambient.sensor != "bme280":
        return None
    if hw is not None:
        return hw.ambient_sensor
    from dyno.hw.bme280 import BME280

    return BME280(sim.bus, rig_cfg.ambient.address, sleep=lambda dt_s: None)  # (the chip converts at once)


def run_ambient(rig_cfg, given: Ambient | None, sensor) -> Ambient:
    """The day a run is corrected to: ``--ambient`` if given, else the sensor, else ``[ambient]``'s day,
    else none (uncorrected)."""
    if given is not None:
        return given
    if sensor is not None:
        return read_sensor(sensor, "BME280", getattr(rig_cfg, "path", "rig.toml"))
    return rig_cfg.ambient.given() or Ambient()


def end_reading(sensor) -> dict | None:
    """The air after the run (logged beside the first; None without a sensor or when it fails now)."""
    if sensor is None:
        return None
    try:
        return read_sensor(sensor, "BME280").to_dict()
    except ConfigError as exc:
        return {"error": str(exc)}


def log_end(ctx) -> None:
    """The air after the run, beside the reading it was corrected to (``ctx.ambient["end"]`` and an
    ``ambient`` document).  Each BME280 transfer is one I2C_RDWR, serialised by the kernel with the
    firmware polls, so reading it while a UI session still polls is safe."""
    end = end_reading(ctx.ambient_sensor)
    if end is not None:
        ctx.ambient = {**ctx.ambient, "end": end}
    if ctx.writer.error is None:
        ctx.writer.doc("ambient", **ctx.ambient)
