"""The run's air: read from the rig's BME280, given (``--ambient``, ``rig.toml [ambient]``), or none.

Thin adapter between the pure :mod:`dyno.analysis.air` and the bus (:mod:`dyno.hw.bme280`, or the
simulated chip the simulated bus serves when ``rig.toml`` declares one).  The composition root reads
the air before the run starts (seconds before GO, while nothing else uses the bus) and after it ends;
the first reading takes the engine map to the run's day (SAE J1349), both are logged.
"""

from __future__ import annotations

from dyno.analysis.air import Ambient, check_air
from dyno.errors import ConfigError


def ambient_sensor(rig_cfg, *, sim=None, hw=None, seed: int = 0):
    """The rig's BME280 driver (None when ``rig.toml`` declares none).  On the simulated rig the chip is
    plugged into the simulated bus here: it exists only when the rig file says it is fitted."""
    if rig_cfg.ambient.sensor != "bme280":
        return None
    if hw is not None:
        return hw.ambient_sensor
    from dyno.hw.bme280 import BME280
    from dyno.sim.bme280_chip import SimBME280

    sim.bus.devices[rig_cfg.ambient.address] = SimBME280(sim.model.world, seed)
    return BME280(sim.bus, rig_cfg.ambient.address, sleep=lambda dt_s: None)  # (the chip converts at once)


def read_sensor(sensor, what: str, rig_path: str = "rig.toml") -> Ambient:
    """One reading as an :class:`Ambient`; a sensor that fails or reads nonsense: ConfigError naming
    ``[ambient] sensor`` (the run is refused in one line, exit 2)."""
    from dyno.hw.bme280 import AmbientSensorError

    try:
        t, p, rh = sensor.read()
        check_air(t, p, rh, what)
    except (AmbientSensorError, ValueError) as exc:
        raise ConfigError(rig_path, "[ambient] sensor", f"\"bme280\" is declared but does not answer with a plausible "
                          f"day ({exc}); check its wiring and address, or set sensor = \"none\"") from None
    return Ambient(round(t, 3), round(p, 4), round(rh, 2), "sensor")


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
