"""The calibration wizard's acquisition glue: the poller listener that feeds it, and a whole simulated session.

Split from :mod:`dyno.ui.calibration_wizard` (the pure state machine, which this imports; nothing there
imports this).
"""

from __future__ import annotations

from dyno.ui.calibration_wizard import COLLECTING_PHASES, CalibrationWizard


class WizardFeeder:
    """Poller listener: hands the ADC conversions to the wizard while it collects.

    With the poller's ``reader``, a step's conversions start only once the host has caught up with the
    device (a frame without MORE after the step began): conversions still queued in the firmware's ring
    from before the load was hung are not the load's, and a backlog longer than the settling samples
    (the simulated fixture at ``--speed N`` buffers N times the Nano's ring; a busy host) would
    otherwise be averaged into the step.
    """

    def __init__(self, wizard: CalibrationWizard, adc_channel: int | None = None, reader=None) -> None:
        self.wizard = wizard
        self.reader = reader
        self._generation = wizard.generation
        self._catching_up = False
        if adc_channel is None:  # the wire's channel of the wizard's converter (v1 CH_ADC; v2 CH_INPUT)
            adc_channel = 4 if wizard.channel == "input" else 3
        self.adc_channel = adc_channel
        self.on_step_done = None  # callable() after a step completes
        self.last_codes: list[int] = []  # the latest conversions, for the live reading

    def __call__(self, events, now_s: float) -> None:
        codes = [e.code for e in events if e.channel == self.adc_channel]
        if codes:
            self.last_codes = (self.last_codes + codes)[-250:]
        if self.wizard.generation != self._generation:  # a step (re)started since the last poll
            self._generation = self.wizard.generation
            self._catching_up = self.reader is not None
        if self._catching_up:
            self._catching_up = bool(getattr(self.reader, "more", False))
            return  # these conversions were queued before the step began
        if not codes:
            return
        if self.wizard.collecting:
            statuses = [e.status for e in events if e.channel == self.adc_channel]
            if self.wizard.add_samples(codes, statuses) and self.on_step_done is not None:
                self.on_step_done()


async def run_sim_calibration(wizard: CalibrationWizard, *, seed: int = 0, settle_wait_s: float = 0.0,
                              **fixture_kw):
    """Drive a whole calibration on the simulated fixture (the simulated operator hangs each mass).

    For tests and the benchmark: run it on a :class:`dyno.clock.VirtualTimeLoop`.
    Returns the :class:`~dyno.sim.ui_fixture.FixtureRig`.
    """
    import asyncio

    from dyno.sim.ui_fixture import build_fixture_poller

    loop = asyncio.get_running_loop()
    t0 = loop.time()
    if wizard.channel == "input":
        fixture_kw = {"input_fitted": True, **fixture_kw}
    rig, poller = build_fixture_poller(lambda: loop.time() - t0, seed=seed, **fixture_kw)
    feeder = WizardFeeder(wizard, reader=poller.reader)
    poller.listeners.append(feeder)
    done = asyncio.Event()
    feeder.on_step_done = done.set
    task = asyncio.create_task(poller.run())
    try:
        wizard.start()
        while wizard.phase in COLLECTING_PHASES:
            s = wizard.current
            if s.from_zero:
                rig.hang(0.0, wizard.radius_m, wizard.channel)
            rig.hang(s.mass_kg, wizard.radius_m, wizard.channel)
            if settle_wait_s:
                await asyncio.sleep(settle_wait_s)
            done.clear()
            wizard.begin_step()
            await done.wait()
            if wizard.step_error:
                raise RuntimeError(wizard.step_error)
    finally:
        poller.stop()
        await asyncio.gather(task, return_exceptions=True)
    return rig
