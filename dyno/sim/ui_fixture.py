"""The simulated rig in its calibration fixture: secondary locked, a mass on a rope.

:class:`dyno.sim.physics.RigModel` has no way to hold the secondary still
and apply a static torque, so this stands in for it on the simulated bus.
It duck-types the part of ``RigModel`` that :class:`dyno.sim.bus.SimSMBus`
uses (``t_s``, ``step(dt_s)``, ``rotor_temp_c``, ``params``), so the ADC
samples reach the host through the same emulated firmware, frames and
reader as a test run; only the physics is replaced.

Signal chain (the same model as ``RigModel._adc_event``)::

    T_sec = m g r * 32/61                          (the applied load, N·m)
    T_sig = T_sec + (T_prev - T_sec) exp(-t/tau)    (rope swing + lock-in filter settling)
    code  = round(offset + gain * T_sig + (sigma0 + sigma1 |T_sig|) n),  n ~ N(0, 1)

The true ``gain`` and ``offset`` are hidden: drawn from the seed around the
thesis values, so a wizard that reproduced the defaults instead of measuring
would fail the test that compares its fit with :attr:`true_gain_counts_per_nm`
and :attr:`true_offset_counts`.

With ``input_fitted`` (rig.toml ``[input_torque]``) the fixture also has the
engine-side channel (issue 27): the engine off on its free cradle, masses hung
on the cradle's arm (``T = m g L``, crank torque), read by the second AD7171
("input" events) with the gain and offset a run on the same seed draws
(:func:`dyno.sim.world.input_channel_truth`: :attr:`true_input_gain_counts_per_nm`,
:attr:`true_input_offset_counts`) and the converter's own rate, clock and
noise (``RigParams.input_*``, as :mod:`dyno.sim.input_torque`).  Both channels
convert throughout; a load hangs on one of them (``hang(..., channel=)``).
The cradle's trunnion bearings hold up to ``b`` (the run's
``cradle_bearing_loss_nm`` for the seed) off the cell, Coulomb friction: after
a load change the cell reads the load moved by as little as it can, i.e. the
previous reading clamped to ``[T - b, T + b]`` — ``T - b`` while loading,
``T + b`` while unloading, up to ``+b`` at no load after unloading: a
hysteresis of ``2b``.  Not modelled: any change between repeats but the noise
(the rope or hook re-seated, temperature).
"""

from __future__ import annotations

import math

import numpy as np

from dyno.analysis.calibration_history import G_STANDARD_M_PER_S2, GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY


class _Event:
    """Shape of :class:`dyno.sim.rig_signals.SensorEvent` (avoids importing the physics)."""

    __slots__ = ("channel", "t_s", "code", "status")

    def __init__(self, channel: str, t_s: float, code: int, status: int = 0) -> None:
        self.channel, self.t_s, self.code, self.status = channel, t_s, code, status


class FixtureParams:
    """The few sensor-chain numbers the fixture needs (defaults: ``RigParams``)."""

    def __init__(self, params=None) -> None:
        if params is None:
            from dyno.sim.rig_params import RigParams

            params = RigParams()
        self.adc_gain_counts_per_nm = params.adc_gain_counts_per_nm
        self.adc_offset_counts = params.adc_offset_counts
        self.adc_rate_hz = params.adc_rate_hz
        self.adc_clock_error_frac = params.adc_clock_error_frac
        self.adc_noise_counts = params.adc_noise_counts
        self.adc_noise_counts_per_nm = params.adc_noise_counts_per_nm
        self.ambient_temp_c = params.ambient_temp_c
        self.rig_params = params  # the simulator's own (the input channel's truth is drawn from them)
        self.input_rate_hz = params.input_rate_hz
        self.input_clock_error_frac = params.input_clock_error_frac
        self.input_noise_counts = params.input_noise_counts
        self.input_noise_counts_per_nm = params.input_noise_counts_per_nm


class CalibrationFixture:
    """Duck-typed ``RigModel`` for :class:`~dyno.sim.bus.SimSMBus` with the secondary locked.

    Parameters
    ----------
    params : RigParams, optional
        Sensor chain (gain, offset, noise, ADC rate); default the thesis rig.
    seed : int
        Noise and hidden-truth seed.
    gain_spread_frac, offset_spread_counts : float
        The hidden true gain is ``params gain * (1 + U(-s, s))``, the offset
        ``params offset + U(-s, s)`` (0 reproduces ``params`` exactly).
    settle_tau_s : float
        Time constant of the load settling after a change (swing + filter).
    nonlinearity_counts_per_nm2 : float
        A quadratic term, to make a fit fail its R^2 check in tests.
    """

    def __init__(self, params=None, seed: int = 0, *, gain_spread_frac: float = 0.03,
                 offset_spread_counts: float = 400.0, settle_tau_s: float = 0.15,
                 nonlinearity_counts_per_nm2: float = 0.0, input_fitted: bool = False,
                 cradle_friction: bool = True,
                 gear_ratio_brake_per_secondary: float = GEAR_RATIO_THESIS_BRAKE_PER_SECONDARY,
                 g_m_per_s2: float = G_STANDARD_M_PER_S2) -> None:
        self.params = FixtureParams(params)
        p = self.params
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA1]))
        self.true_gain_counts_per_nm = p.adc_gain_counts_per_nm * (1.0 + rng.uniform(-1, 1) * gain_spread_frac)
        self.true_offset_counts = p.adc_offset_counts + rng.uniform(-1, 1) * offset_spread_counts
        self.nonlinearity_counts_per_nm2 = nonlinearity_counts_per_nm2
        self.gear_ratio = gear_ratio_brake_per_secondary
        self.g_m_per_s2 = g_m_per_s2
        self.settle_tau_s = settle_tau_s
        self._rng = np.random.default_rng(np.random.SeedSequence([seed, 0xADC]))
        self._adc_period_s = 1.0 / (p.adc_rate_hz * (1.0 + p.adc_clock_error_frac))
        self.t_s = 0.0
        self._ahead: list = []  # conversions made beyond t_s (a firmware in the loop asked for them early)
        self._made_until_s = 0.0
        self._next_adc_t = float(rng.uniform(0.0, self._adc_period_s))
        self._target_nm = 0.0
        self._from_nm = 0.0
        self._change_t_s = 0.0
        self.rotor_temp_c = p.ambient_temp_c  # locked rotor: nothing heats it
        # drill knobs, as on RigModel: error bit on conversions, one code repeated forever
        self.adc_error_prob = 0.0
        self.adc_stuck = False
        self._adc_stuck_code: int | None = None
        self._rng_err = np.random.default_rng(np.random.SeedSequence([seed, 0xE77]))
        # the engine-side input channel (issue 27): its truth as a run on this seed draws it
        self.input_fitted = bool(input_fitted)
        self.input_error_prob = 0.0  # drill adc-error:input
        self.input_stuck = False     # drill adc-stuck:input
        self._input_stuck_code: int | None = None
        self._in_load = [0.0, 0.0, 0.0]  # target N m, from N m, change time s
        if self.input_fitted:
            from dyno.sim.world import input_channel_truth

            self.true_input_gain_counts_per_nm, self.true_input_offset_counts, bearing = input_channel_truth(
                p.rig_params, seed)
            self.cradle_bearing_nm = bearing if cradle_friction else 0.0
            ss = np.random.SeedSequence([seed, 0x1C])
            s_noise, s_err, s_phase = ss.spawn(3)
            self._in_rng = np.random.default_rng(s_noise)
            self._in_rng_err = np.random.default_rng(s_err)
            self._in_period_s = 1.0 / (p.input_rate_hz * (1.0 + p.input_clock_error_frac))
            self._next_in_t = float(np.random.default_rng(s_phase).uniform(0.0, self._in_period_s))

    # --- the simulated operator -----------------------------------------------------
    def hang(self, mass_kg: float, radius_m: float, channel: str = "output") -> float:
        """Hang ``mass_kg`` on the rope at ``radius_m`` (``channel="input"``: on the cradle's arm at
        ``radius_m``); returns the true torque (N·m: secondary, or crank on the input channel)."""
        if channel == "input":
            if not self.input_fitted:
                raise ValueError("the fixture has no input torque channel")
            torque_nm = mass_kg * self.g_m_per_s2 * radius_m
            b = self.cradle_bearing_nm  # the bearings move the cell's reading as little as they can
            cell_nm = min(max(self._in_load[0], torque_nm - b), torque_nm + b)
            self._in_load = [cell_nm, self._in_signal_nm(self.t_s), self.t_s]
            return torque_nm
        torque_nm = mass_kg * self.g_m_per_s2 * radius_m * self.gear_ratio
        self._from_nm = self.signal_nm(self.t_s)
        self._target_nm = torque_nm
        self._change_t_s = self.t_s
        return torque_nm

    def _in_signal_nm(self, t_s: float) -> float:
        target, start, t0 = self._in_load
        if self.settle_tau_s <= 0:
            return target
        return target + (start - target) * math.exp(-max(0.0, t_s - t0) / self.settle_tau_s)

    def signal_nm(self, t_s: float) -> float:
        if self.settle_tau_s <= 0:
            return self._target_nm
        decay = math.exp(-max(0.0, t_s - self._change_t_s) / self.settle_tau_s)
        return self._target_nm + (self._from_nm - self._target_nm) * decay

    def true_counts(self, torque_nm: float) -> float:
        return (self.true_offset_counts + self.true_gain_counts_per_nm * torque_nm
                + self.nonlinearity_counts_per_nm2 * torque_nm * torque_nm)

    # --- what SimSMBus calls ------------------------------------------------------------
    def step(self, dt_s: float) -> list:
        if not dt_s >= 0.0:
            raise ValueError("dt_s must be >= 0")
        t_end = self.t_s + dt_s
        self._make(t_end)
        k = sum(1 for ev in self._ahead if ev.t_s <= t_end)
        out, self._ahead = self._ahead[:k], self._ahead[k:]
        self.t_s = t_end
        return out

    def events_ahead(self, until_s: float) -> list:
        """The conversions in ``(t, until_s]`` without advancing ``t`` (a firmware in the loop needs those that fall
        during a bus transfer before it runs; a load hung before ``until_s`` shows from the conversion after)."""
        self._make(until_s)
        return [ev for ev in self._ahead if self.t_s < ev.t_s <= until_s]

    def _make(self, t_end: float) -> None:
        """Every conversion up to ``t_end``, in time order, onto the queue."""
        if t_end <= self._made_until_s:
            return
        p = self.params
        out = []
        while self._next_adc_t <= t_end:
            ta = self._next_adc_t
            t_sig = self.signal_nm(ta)
            sigma = p.adc_noise_counts + p.adc_noise_counts_per_nm * abs(t_sig)
            code, status = self._convert(self.true_counts(t_sig), sigma, self._rng, self.adc_error_prob,
                                         self._rng_err, "_adc_stuck_code" if self.adc_stuck else None)
            out.append(_Event("adc", ta, code, status))
            self._next_adc_t = ta + self._adc_period_s
        if self.input_fitted:
            self._input_events(t_end, out)
            out.sort(key=lambda e: e.t_s)
        self._ahead.extend(out)
        self._made_until_s = t_end

    def _input_events(self, t_end: float, out: list) -> None:
        """The second converter's conversions up to ``t_end`` (the noise model of :mod:`dyno.sim.input_torque`)."""
        p = self.params
        while self._next_in_t <= t_end:
            ta = self._next_in_t
            sig = self._in_signal_nm(ta)
            sigma = p.input_noise_counts + p.input_noise_counts_per_nm * abs(sig)
            code, status = self._convert(self.true_input_offset_counts + self.true_input_gain_counts_per_nm * sig,
                                         sigma, self._in_rng, self.input_error_prob, self._in_rng_err,
                                         "_input_stuck_code" if self.input_stuck else None)
            out.append(_Event("input", ta, code, status))
            self._next_in_t = ta + self._in_period_s

    def _convert(self, counts: float, sigma: float, rng, error_prob: float, rng_err,
                 stuck_attr: str | None) -> tuple[int, int]:
        """One conversion of a converter: (16-bit code, status) for the true ``counts`` with its white noise, an
        error bit at ``error_prob``, and when stuck (``stuck_attr`` names where the first stuck code is kept) that
        code again."""
        code = min(65535, max(0, math.floor(counts + sigma * float(rng.standard_normal()) + 0.5)))
        status = 0x20 if error_prob and rng_err.random() < error_prob else 0
        if stuck_attr is not None:
            if getattr(self, stuck_attr) is None:
                setattr(self, stuck_attr, code)
            code = getattr(self, stuck_attr)
        return code, status


class FixtureRig:
    """Fixture + emulated firmware + simulated bus, ready for a reader and a poller."""

    def __init__(self, now_s, *, seed: int = 0, params=None, pace: float | None = None, firmware_elf: dict | None = None,
                 **fixture_kw) -> None:
        from dyno.sim.bus import SimSMBus
        from dyno.sim.device import EmulatedFirmware

        self.fixture = CalibrationFixture(params, seed, **fixture_kw)
        self.model = self.fixture  # what the drills act on (dyno.session.drills), as SimRig.model
        # paced at N x real time (dyno calibrate --speed N): the ring holds the same span of fixture time
        # (two converters: twice the events); None: the firmware's own 64
        per_poll = 128 if self.fixture.input_fitted else 64
        ring = 64 if pace is None else max(per_poll, math.ceil(per_poll * pace))
        if firmware_elf is not None:  # the Nano's own ELF in simavr (dyno calibrate --firmware-elf)
            from dyno.sim.elf_firmware import ElfFirmware

            self.firmware = ElfFirmware(firmware_elf["elf"], i2c_khz=firmware_elf["i2c_khz"],
                                        address=firmware_elf["address"], input_fitted=self.fixture.input_fitted,
                                        events_ahead=self.fixture.events_ahead)
        else:
            self.firmware = EmulatedFirmware("v2", input_fitted=self.fixture.input_fitted, ring_capacity=ring)
        self.bus = SimSMBus(self.fixture, self.firmware, now_s, seed=seed)

    def close(self) -> None:
        """End what the fixture started (the simavr harness of ``--firmware-elf``)."""
        close = getattr(self.firmware, "close", None)
        if close is not None:
            close()

    def hang(self, mass_kg: float, radius_m: float, channel: str = "output") -> float:
        self.bus.sync()  # the load changes now, not at the last poll
        return self.fixture.hang(mass_kg, radius_m, channel)


def build_fixture_poller(now_s, *, seed: int = 0, poll_hz: float = 150.0, address: int = 0x03, pace: float | None = None,
                         want_input: bool | None = None, **fixture_kw):
    """(FixtureRig, Poller) over the simulated bus: what ``dyno calibrate --sim`` acquires from.

    ``input_fitted=True`` (a fixture option): the input channel too, asked for at boot as a run does
    (``want_input``: asked for or not whatever is fitted; None: when fitted).  ``pace``: N at N x real time
    (each real-time poll drains and buffers N x more)."""
    from dyno.acquisition.poller import Poller
    from dyno.acquisition.reader import make_reader
    from dyno.transports.base import I2CTransport

    rig = FixtureRig(now_s, seed=seed, pace=pace, **fixture_kw)
    reader = make_reader("v2", I2CTransport(rig.bus, address),
                         want_input=rig.fixture.input_fitted if want_input is None else want_input)
    return rig, Poller(reader, poll_hz=poll_hz, max_burst=max(8, math.ceil(8 * (pace or 1.0))))
