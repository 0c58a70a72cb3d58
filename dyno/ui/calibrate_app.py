"""The calibration wizard screen (``dyno calibrate``): thin over :mod:`dyno.ui.calibration_wizard`.

Acquisition is the same poller as a test (the fixture's ADC conversions go
through the emulated firmware and the bus in ``--sim``; the real link on the
rig); the poller's listener feeds the wizard, this screen shows it at a few Hz.
Nothing here moves hardware: the rig stays in its safe state throughout (the
secondary is locked by hand), so there is nothing to confirm but the
acceptance, which is what writes the history.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.widgets import Input, ProgressBar, Static
from textual_plotext import PlotextPlot

from dyno.ui.calibration_feed import WizardFeeder
from dyno.ui.calibration_wizard import COLLECTING_PHASES, CalibrationWizard, Phase, parse_masses
from dyno.ui.common import ESTOP_KEYS, ConfirmScreen, DynoApp, EstopSafeInput, bottom_lines, detach_terminal, exit_after

HELP = "Enter/c collect  r redo  a accept  x reject  q quit │ SPACE/^C E-STOP"
DEFAULT_RADIUS_M = 0.15
DEFAULT_MASSES = "5,10,20,30,40"
# the engine-side input channel (issue 27): masses on the cradle's arm (hardware/README.md: 0…10 kg on 0.2 m)
DEFAULT_INPUT_ARM_M = 0.2
DEFAULT_INPUT_MASSES = "2,4,6,8,10"
STEPS_SHOWN = 14  # rows of the steps table (a window round the current step when there are more)

CAL_CSS = """
#title { height: 1; background: $primary; color: $text; text-style: bold; }
#phase { height: 1; text-style: bold; }
#instruction { height: 2; }
#setup { height: auto; }
#setup Input { width: 1fr; }
#progress { height: 1; }
#body { height: 1fr; }
#steps { width: 44; }
#right { width: 1fr; }
#reading { height: 1; }
#result { height: auto; }
#resid { height: 1fr; }
"""


@dataclass
class CalibrateOptions:
    sim: bool = True
    seed: int = 0
    speed: float = 1.0  # sim only: fixture time runs this many times faster than the loop's
    n_samples: int = 500
    settle_samples: int = 125
    history_path: Path | None = None
    rig_path: Path | None = None
    radius_m: float = DEFAULT_RADIUS_M
    masses: str = DEFAULT_MASSES
    fixture_kw: dict | None = None  # sim only: CalibrationFixture options (tests)
    drills: list = None  # dyno.session.drills.Drill (sim only), from the first frame
    channel: str = "output"  # "output" (brake side) | "input" (engine cradle, issue 27)
    repeats: int = 1  # passes of the load sequence; from 2 on the slope's reproducibility is shown
    in_force_path: Path | None = None  # the channel's calibration in force when history_path is new
    mock_pins: bool = False  # sim only: the rig's outputs through the Pi's own code on the wiring twin
    firmware_elf: Path | None = None  # sim only: the Nano's real ELF in simavr as the fixture's Nano


class CalibrateApp(DynoApp):
    CSS = DynoApp.CSS + CAL_CSS
    BINDINGS = DynoApp.BINDINGS + [
        # priority: they act even while a number field has the focus (EstopSafeInput declines letters)
        Binding("c", "collect", "collect", priority=True), Binding("enter", "collect", show=False),
        Binding("r", "redo", "redo", priority=True), Binding("a", "accept", "accept", priority=True),
        Binding("x", "reject", "reject", priority=True), Binding("q", "quit_safe", "quit", priority=True),
        Binding("escape", "leave_input", show=False),
    ]

    def __init__(self, opts: CalibrateOptions | None = None) -> None:
        super().__init__()
        self.opts = opts or CalibrateOptions()
        self.wizard: CalibrationWizard | None = None
        self.feeder: WizardFeeder | None = None
        self.poller = None
        self.rig = None  # FixtureRig (sim) or HardwareRig
        self.cal_ctx = None  # dyno.session.calibration.CalibrationContext
        self._old_signals: dict = {}
        self.calibration_in_force = None
        self._poll_task = None
        self._drawn = None

    def compose(self) -> ComposeResult:
        mode = f"SIM x{self.opts.speed:g} seed {self.opts.seed}" if self.opts.sim else "RIG"
        yield Static(f" dyno calibrate │ {mode} │ {self.opts.channel} │ history: {self.opts.history_path}",
                     id="title")
        yield Static(f" E-STOP: {ESTOP_KEYS} (always active)", id="estop")
        yield Static("", id="phase")
        yield Static("", id="instruction")
        with Horizontal(id="setup"):
            yield EstopSafeInput(str(self.opts.radius_m), id="radius",
                                 placeholder="arm length m" if self.opts.channel == "input" else "rope radius m",
                                 restrict=r"[0-9.eE+-]*")
            yield EstopSafeInput(self.opts.masses, placeholder="masses kg, comma-separated", id="masses",
                                 restrict=r"[0-9.,eE+-]*")
        yield ProgressBar(total=1.0, show_eta=False, id="progress")
        with Horizontal(id="body"):
            yield Static("", id="steps")
            with Vertical(id="right"):
                yield Static("", id="reading")
                yield Static("", id="result")
                yield PlotextPlot(id="resid")
        yield bottom_lines(HELP)

    async def on_mount(self) -> None:
        from dyno.analysis.calibration_history import latest, load_history
        from dyno.session.calibration_files import calibration_in_force
        from dyno.errors import DynoError

        history = []
        hist_path = self.opts.history_path
        try:
            if hist_path and Path(hist_path).exists():
                history = load_history(hist_path)
            self.calibration_in_force = latest(history or load_history(self.opts.in_force_path
                                                                       or calibration_in_force()))
        except DynoError:
            self.calibration_in_force = None  # first calibration: nothing to compare the tare with
        self.wizard = CalibrationWizard(n_samples=self.opts.n_samples, settle_samples=self.opts.settle_samples,
                                        previous=self.calibration_in_force, channel=self.opts.channel,
                                        repeats=self.opts.repeats, history=history)
        try:
            self._start_acquisition()
        except DynoError as exc:
            self.exit(return_code=2, message=f"dyno calibrate: error: {exc}")
            return
        self.set_interval(0.25, self.refresh_view)
        self.query_one("#radius", Input).focus()
        self.refresh_view()

    def _start_acquisition(self) -> None:
        from dyno.session.calibration import build_calibration

        loop = asyncio.get_running_loop()
        self.cal_ctx = build_calibration(sim=self.opts.sim, loop=loop, seed=self.opts.seed, speed=self.opts.speed,
                                         rig_path=self.opts.rig_path, fixture_kw=self.opts.fixture_kw,
                                         drills=self.opts.drills, on_trip=self._on_trip,
                                         mock_pins=self.opts.sim and self.opts.mock_pins,
                                         firmware_elf=self.opts.firmware_elf if self.opts.sim else None)
        self.rig = self.cal_ctx.sim or self.cal_ctx.hw
        self.poller = self.cal_ctx.poller
        self.feeder = WizardFeeder(self.wizard, reader=self.poller.reader)
        self.feeder.on_step_done = self._step_done
        self.poller.listeners.append(self.feeder)
        self._poll_task = asyncio.create_task(self.poller.run())
        self._install_signal_handlers(loop)

    def _on_trip(self, trip) -> None:
        """A fault ended the calibration: outputs already safe (build_calibration), nothing written."""
        self.wizard.abort(trip.cause, trip.detail)
        self.query_one("#estop", Static).update(f" ABORTED ({trip.cause}) │ rig SAFE │ nothing written │ q quit")
        self.say(f"ABORTED: {trip.cause}: {trip.detail}")
        self.refresh_view()

    def _install_signal_handlers(self, loop) -> None:
        """SIGTERM/SIGHUP/SIGINT (systemd, a closed terminal, kill -INT): safe state, calibration aborted,
        exit 128+N.  (The Ctrl+C key is the E-STOP: in raw mode it arrives as a key, not as SIGINT.)"""
        import signal

        from dyno.control.safety import Trip

        def on_loop(signum: int) -> None:
            if self.cal_ctx.trip is None:
                self.cal_ctx.trip = Trip("signal", f"{signal.Signals(signum).name} received", loop.time())
                self._on_trip(self.cal_ctx.trip)
            self.call_later(self._quit_code, 128 + signum)

        def handler(signum, frame) -> None:
            if self.cal_ctx.hw is not None:
                self.cal_ctx.hw.actuators.safe_state(latch=True)  # at once, latched
            if signum == signal.SIGHUP:
                detach_terminal()  # (after the safe state) or Textual's shut-down waits on the dead terminal
            loop.call_soon_threadsafe(on_loop, signum)

        self._old_signals = {sig: signal.signal(sig, handler)
                             for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)}

    async def _quit_code(self, code: int) -> None:
        await self._stop_rig()  # safe state and the rig released first
        # A hang-up left Textual restoring a terminal that is gone (it waited for ever on its output thread,
        # the wizard holding the pins and the bus): the handler now detaches the terminal; should the exit
        # still not have happened within a grace, it is forced.
        exit_after(code, grace_s=0.8)
        self.exit(return_code=code)

    # --- view ----------------------------------------------------------------------------------
    def refresh_view(self) -> None:
        w = self.wizard
        if w is None:
            return
        step = w.current
        phase = w.phase.value.upper().replace("_", " ")
        if step is not None:
            phase += f"  step {w.index + 1}/{len(w.steps)}"
            if w.repeats > 1 and step.direction != 0:
                phase += f"  repeat {step.repeat + 1}/{w.repeats}"
            phase += "  COLLECTING" if w.collecting else ""
        self.query_one("#phase", Static).update(" " + phase)
        self.query_one("#instruction", Static).update(" " + w.instruction())
        self.query_one("#setup").display = w.phase is Phase.SETUP
        self.query_one("#progress", ProgressBar).update(progress=w.progress)
        self.query_one("#steps", Static).update(self._steps_text())
        self.query_one("#reading", Static).update(self._reading_text())
        result = Text("\n".join(w.result_lines()))
        if w.rejection:
            result.stylize("bold red")
        elif w.fit is not None:
            result.stylize("green")
        self.query_one("#result", Static).update(result)
        self._draw_residuals()

    def _steps_text(self) -> Text:
        w = self.wizard
        t = Text("  # pass     kg    N·m    mean     sd   n\n", style="bold")
        first = 0
        if len(w.steps) > STEPS_SHOWN:  # a window round the current step (the last ones in review)
            at = w.index if w.phase in COLLECTING_PHASES else len(w.steps)
            first = max(0, min(at - STEPS_SHOWN // 2, len(w.steps) - STEPS_SHOWN))
        for i, s in enumerate(w.steps[first:first + STEPS_SHOWN], start=first):
            mark = ">" if i == w.index and w.phase in COLLECTING_PHASES else " "
            pas = {1: "load", -1: "unld", 0: "tare"}[s.direction]
            mean = f"{s.mean_counts:7.1f}" if s.n else "      —"
            sd = f"{s.std_counts:6.1f}" if s.n > 1 else "     —"
            t.append(f"{mark}{i + 1:2d} {pas} {s.mass_kg:6.1f} {s.torque_nm:6.2f} {mean} {sd} {s.n:3d}\n")
        return t

    def _reading_text(self) -> str:
        codes = self.feeder.last_codes if self.feeder else []
        if not codes and self.opts.channel == "input" and getattr(self.poller.reader, "input_present", None) is False:
            return "NO input converter (firmware)"  # it announced none at boot: old firmware, or not fitted
        if not codes:
            return "ADC: waiting for conversions"
        mean = float(np.mean(codes[-125:]))
        txt = f"ADC now {mean:8.1f} counts"
        if self.calibration_in_force is not None:
            txt += f" = {self.calibration_in_force.torque_secondary_nm(mean):+.2f} N·m (cal. in force)"
        return txt

    def _draw_residuals(self) -> None:
        w = self.wizard
        key = (w.phase, id(w.fit))
        if key == self._drawn:
            return
        self._drawn = key
        plot = self.query_one("#resid", PlotextPlot)
        plt = plot.plt
        plt.clear_data()
        plt.clear_figure()
        f = w.fit
        if f is None:
            plt.title("residuals (after the fit)")
        else:
            steps = w.load_steps()
            for sign, colour, label in ((1, "cyan", "loading"), (-1, "magenta", "unloading")):
                xs = [x for x, s in zip(f.torques_nm, steps) if s.direction == sign]
                ys = [float(r) for r, s in zip(f.residuals_counts, steps) if s.direction == sign]
                if xs:
                    plt.scatter(xs, ys, color=colour, label=label)
            plt.hline(0.0, color="gray")
            plt.title("residual counts vs N·m")
        plot.refresh()

    # --- acquisition callbacks ---------------------------------------------------------------------
    def _step_done(self) -> None:
        w = self.wizard
        if w.step_error:
            self.say(f"step stopped: {w.step_error}")
        elif w.phase is Phase.REVIEW:
            self.say("all steps done: review the fit" if w.acceptable else f"fit refused: {w.rejection}")
        else:
            self.say(f"step done; next: {w.instruction()[:60]}")

    # --- keys ------------------------------------------------------------------------------------------
    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id == "radius":
            self.query_one("#masses", Input).focus()
            return
        self._configure()

    def _configure(self) -> bool:
        w = self.wizard
        try:
            masses = parse_masses(self.query_one("#masses", Input).value)
        except ValueError as exc:
            self.say(str(exc))
            return False
        problems = w.configure(self.query_one("#radius", Input).value, masses)
        if problems:
            self.say("; ".join(problems))
            return False
        w.start()
        for inp in self.query(Input):
            inp.disabled = True  # nor can a dialog closing hand them the focus back: keys drive the wizard now
        self.set_focus(None)
        reps = f"{w.repeats} x " if w.repeats > 1 else ""
        self.say(f"{len(w.steps)} steps planned: tare, {reps}({len(w.masses_kg)} loading, "
                 f"{len(w.masses_kg) - 1} unloading), tare")
        self.refresh_view()
        return True

    def check_action(self, action: str, parameters) -> bool | None:
        # The wizard's keys are priority bindings (so a number field cannot eat them); while a
        # dialog asks a question they must not act behind it.
        from textual.screen import ModalScreen

        if action in ("collect", "redo", "accept", "reject") and isinstance(self.screen, ModalScreen):
            return False
        return True

    def action_collect(self) -> None:
        w = self.wizard
        if w.phase is Phase.SETUP:
            self._configure()
            return
        if w.phase not in COLLECTING_PHASES:
            self.say("nothing to collect now")
            return
        if w.collecting:
            self.say("collecting… (r restarts this step)")
            return
        s = w.current
        if self.opts.sim:  # the simulated operator hangs the load now (a repeat's first: all off first)
            if s.from_zero:
                self.rig.hang(0.0, w.radius_m, w.channel)
            self.rig.hang(s.mass_kg, w.radius_m, w.channel)
        w.begin_step()
        self.say(f"collecting {w.settle_samples} settling + {w.n_samples} samples")

    def action_leave_input(self) -> None:
        self.set_focus(None)

    def action_redo(self) -> None:
        self.wizard.redo_step()
        self.say("step restarted: collect again when the load hangs still")

    def action_accept(self) -> None:
        w = self.wizard
        if not w.acceptable:
            self.say(f"cannot accept: {w.rejection or 'the fit is not ready'}")
            return

        def answered(yes: bool | None) -> None:
            if not yes:
                return
            from dyno.errors import DynoError

            try:
                entry = w.accept(self.opts.history_path)
            except DynoError as exc:
                self.say(f"not written: {exc}")
                return
            self.say(f"appended to {self.opts.history_path} ({entry.date})")
            self.refresh_view()

        self.push_screen(ConfirmScreen(f"Append this calibration to\n{self.opts.history_path}?"), answered)

    def action_reject(self) -> None:
        if self.wizard.phase in (Phase.ACCEPTED, Phase.REJECTED):
            return
        self.wizard.reject()
        self.say("rejected: nothing written")
        self.refresh_view()

    def action_estop(self) -> None:
        self.dismiss_modals()
        if self.wizard is not None:
            self.wizard.redo_step()
        act = getattr(self.rig, "actuators", None)  # the rig's outputs (hardware); the fixture has none
        if act is not None:  # pragma: no cover - rig only
            act.safe_state(latch=True)
        if self.wizard is not None and self.cal_ctx is not None and self.cal_ctx.trip is None:
            from dyno.control.safety import Trip

            self.cal_ctx.trip = Trip("estop", "E-stop (operator)", asyncio.get_running_loop().time())
            self._on_trip(self.cal_ctx.trip)
        self.say("E-STOP: collection stopped" + ("; rig outputs in their safe state" if act is not None
                                                 else "; the calibration fixture has no outputs to stop"))

    async def action_quit_safe(self) -> None:
        await self._stop_rig()
        self.exit(return_code=0)

    async def _stop_rig(self) -> None:
        # Not named `_shutdown`: that is Textual's own App._shutdown, which run_test calls when the
        # test body raises; overriding it left the app running and hung the test instead of failing it.
        if self.poller is not None:
            # The UI's listener goes first: while Textual unmounts, a last poll must not
            # update widgets that are closing (that wait never ends).  The safety check stays.
            if self.feeder in self.poller.listeners:
                self.poller.listeners.remove(self.feeder)
            self.poller.stop()
        if self._poll_task is not None:
            await asyncio.gather(self._poll_task, return_exceptions=True)
            self._poll_task = None
        if self.cal_ctx is not None:
            from dyno.session.calibration import close_calibration

            close_calibration(self.cal_ctx)  # the rig: release stroke finished, pins released
            self.rig = None
        import signal

        for sig, old in self._old_signals.items():
            signal.signal(sig, old)
        self._old_signals = {}

    async def on_unmount(self) -> None:
        await self._stop_rig()


def main(opts: CalibrateOptions) -> int:
    app = CalibrateApp(opts)
    app.run()
    return app.return_code or 0

