"""The real rig in one object: what ``dyno.sim.rig.SimRig`` is for the simulated one.

>>> with HardwareRig(load_rig(args.rig)) as hw:          # doctest: +SKIP
...     asyncio.create_task(hw.watchdog.run())
...     reader = make_reader(cfg.protocol, hw.transport)
...     controller(actuators=hw.actuators, ...)

Entering claims the pins (safe state at once, release stroke starting),
installs the signal/atexit handlers, opens the firmware link (I²C with the
Arduino reset wired in, or USB serial) and the thermometer.  Leaving, by any
path, finishes the release stroke, de-energises everything and closes the
buses.  Every part is injectable (pin factory, clock, bus, serial port), so
the same object runs on a laptop over the simulated bus.
"""

from __future__ import annotations

from dyno.hw.outputs import GpioActuators
from dyno.hw.safety import DEFAULT_SIGNALS, SafetyGuard, Watchdog
from dyno.hw.thermometer import MLX90614


class _CurrentBus:
    """The transport's bus as it is now: recovery may reopen it, the thermometer must follow."""

    def __init__(self, transport) -> None:
        self._transport = transport

    def i2c_rdwr(self, *msgs):
        return self._transport.bus.i2c_rdwr(*msgs)


class HardwareRig:
    def __init__(self, config, *, pin_factory=None, clock=None, bus=None, serial_port=None,
                 install_signals: bool = True, persist_faults: bool | None = None,
                 firmware_transport=None) -> None:
        self.config = config
        # a firmware link already open (dyno doctor's serial port: opening it again would reset the Nano again);
        # used as it is, and left to its owner to close
        self._given_transport = firmware_transport
        # the wiring faults its driver finds outlive the process (dyno.hw.rig_faults): on the real pins only
        self.persist_faults = pin_factory is None if persist_faults is None else persist_faults
        self._pin_factory = pin_factory
        self._clock = clock
        self._bus = bus
        self._serial_port = serial_port
        self._install_signals = install_signals
        self.actuators = self.guard = self.transport = self.thermometer = self.watchdog = None
        self.ambient_sensor = None  # dyno.hw.bme280.BME280 when rig.toml [ambient] sensor = "bme280"
        self.estop = None  # dyno.hw.estop.EstopInput when rig.toml names pins.estop_input
        self._i2c = None

    def __enter__(self) -> "HardwareRig":
        from dyno.transports.i2c import open_i2c
        from dyno.transports.serial import open_serial

        cfg = self.config
        known = ()
        if self.persist_faults:
            from dyno.hw import rig_faults

            known = rig_faults.load()
        self.actuators = GpioActuators(cfg, pin_factory=self._pin_factory, clock=self._clock, known_faults=known)
        if cfg.pins.estop_input is not None:
            from dyno.hw.estop import EstopInput

            try:
                self.estop = EstopInput(cfg.pins.estop_input, self.actuators, pin_factory=self._pin_factory)
            except BaseException:
                self.actuators.close()
                raise
        signals = DEFAULT_SIGNALS if self._install_signals else ()
        self.guard = SafetyGuard(self.actuators, signals=signals, use_atexit=self._install_signals)
        self.guard.__enter__()
        try:
            clock = self.actuators.clock
            # The thermometer is always on I2C; the firmware is on I2C or USB serial.
            self._i2c = open_i2c(cfg, bus=self._bus, reset=self.actuators.reset_arduino, clock=clock)
            if self._given_transport is not None:
                self.transport = self._given_transport
            elif cfg.transport == "serial":
                self.transport = open_serial(cfg, port=self._serial_port, clock=clock)
            else:
                self.transport = self._i2c
            self.thermometer = MLX90614(_CurrentBus(self._i2c), cfg.i2c.thermometer_address)
            if cfg.ambient.sensor == "bme280":  # the air, read by the run before and after (dyno.session.ambient)
                from dyno.hw.bme280 import BME280

                self.ambient_sensor = BME280(_CurrentBus(self._i2c), cfg.ambient.address)
            self.watchdog = Watchdog(self.actuators, cfg.actuator.watchdog_s, clock=clock,
                                     level_checks=(self.estop.poll,) if self.estop is not None else ())
        except BaseException as exc:
            self.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self

    def __exit__(self, exc_type, exc, tb):
        try:
            if self.watchdog is not None:
                self.watchdog.stop_thread()
            if self.guard is not None:
                self.guard.__exit__(exc_type, exc, tb)
        finally:
            self._keep_faults()
            if self.estop is not None:
                self.estop.close()
            owned = (self.transport, self._i2c) if self._given_transport is None else (self._i2c,)
            for link in {id(x): x for x in owned if x is not None}.values():
                try:
                    link.close()
                except OSError:
                    pass
        return False

    def _keep_faults(self) -> None:
        if not self.persist_faults or self.actuators is None:
            return
        new = [f for f in self.actuators.faults if not f.get("inherited")]
        try:
            from dyno.hw import rig_faults

            rig_faults.record(new)
        except OSError as exc:  # the fault is still in this run's record; say that it will not outlive it
            import logging

            logging.getLogger("dyno.outputs").error("cannot keep the wiring faults (%s): %s", exc, new)
