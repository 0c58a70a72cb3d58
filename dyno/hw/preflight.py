"""Before a rig entry point takes over the screen: is the rig's hardware there at all?

``dyno ui`` and ``dyno calibrate`` without ``--sim`` open the pins and the bus inside their Textual app; on a
machine without GPIO or I2C (a laptop, a Pi with I2C disabled, lgpio missing) that would end in a
hundreds-of-lines traceback.  This check says the same thing as ``dyno doctor`` in one line, before anything
is claimed: :class:`RigUnavailable` (a :class:`~dyno.errors.ConfigError`: the CLI prints one line and
exits 2; no output was touched, so nothing needs making safe).
"""

from __future__ import annotations

from pathlib import Path

from dyno.errors import ConfigError


class RigUnavailable(ConfigError):
    """The rig's GPIO, I2C bus or serial port is missing on this machine."""


def check_rig_present(rig_cfg, *, dev: Path = Path("/dev")) -> None:
    """Raise :class:`RigUnavailable` naming what is missing and how to fix it; return if all is there."""
    where = getattr(rig_cfg, "path", None) or "hardware/rig.toml"
    try:
        from gpiozero import Device
        from gpiozero.exc import BadPinFactory
    except ImportError as exc:  # pragma: no cover - gpiozero is a dependency
        raise RigUnavailable(where, "pins", f"gpiozero cannot be imported ({exc}): pip install gpiozero") from None
    if Device.pin_factory is None:
        import warnings

        try:
            with warnings.catch_warnings():  # each factory it falls back from warns: the one line says it all
                warnings.simplefilter("ignore")
                Device.pin_factory = Device._default_pin_factory()
        except BadPinFactory:
            raise RigUnavailable(where, "pins", "no GPIO on this machine (gpiozero found no pin factory: not a "
                                 "Raspberry Pi, or lgpio missing: sudo apt install python3-lgpio); `dyno doctor` "
                                 "checks the rig, `--sim` runs without one") from None
    bus = dev / f"i2c-{rig_cfg.i2c.bus}"
    if not bus.exists():
        from dyno.transports.i2c import missing_bus_hint

        raise RigUnavailable(where, "i2c.bus", f"{bus} is missing ({missing_bus_hint(rig_cfg.i2c.bus)}); "
                             "`dyno doctor` checks the rig")
    if getattr(rig_cfg, "transport", "i2c") == "serial":
        port = Path(rig_cfg.serial.port)
        if not port.exists():
            raise RigUnavailable(where, "serial.port", f"{port} is missing (Nano unplugged, or another port: "
                                 "ls /dev/ttyUSB* /dev/ttyACM*)")
