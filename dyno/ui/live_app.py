"""The live run screen (``dyno ui``): state, live values, plots, and the operator's keys.

Thin over :mod:`dyno.ui.session` (commands) and :mod:`dyno.ui.live_model`
(values).  The poller and the controller run as tasks on Textual's own
loop; this screen only reads them, at ``REFRESH_HZ``, and hands the slow
thing (the belt-model overlay, :mod:`dyno.ui.live_overlay`) to a background
process.  The plots are drawn by :mod:`dyno.ui.live_plots`.
"""

from __future__ import annotations

import math
import time

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.css.query import NoMatches
from textual.widgets import Static
from textual_plotext import PlotextPlot

from dyno.control.registry import FROM_IDLE  # the characterisations: no steady points, no point count or ETA
from dyno.ui.common import ESTOP_KEYS, ConfirmScreen, DynoApp, Readout, bottom_lines
from dyno.analysis.live import RateMeter, ideal_engine_rpm, live_values
from dyno.analysis.u95_terms import COMPARE_NOTE_SHORT, TERM_SHORT, largest_term
from dyno.ui.live_model import History, fmt, go_text, temp_colour
from dyno.ui.live_model import (TEST_STATES, discard_text, efficiency_text, last_point_text, measure_text,
                                progress_text)
from dyno.ui.live_overlay import OverlayMixin
from dyno.ui.live_plots import PLOTS, draw_efficiency, draw_shift_curve, draw_time
from dyno.ui.results_view import has_results, results_lines
from dyno.ui.session import LiveOptions, LiveSession

REFRESH_HZ = 4.0  # values during a test: a few Hz, readable
IDLE_REFRESH_HZ = 1.0  # ... and while nothing runs (waiting, armed, ended): a refresh costs ~2 ms of loop time, the idle is mostly wake-ups
PLOT_PERIOD_S = 1.0  # a plotext redraw costs ~25-50 ms of loop time: at most once a second unless the view changed
HELP = "g GO  p pause  m manual  [ ] jog  1-3 plot  o overlay  q quit  │ SPACE/^C E-STOP"
HELP_ENDED = "r re-arm (new run)  1-3 plot  4 results  o overlay  q quit  │ SPACE/^C E-STOP"  # after DONE/ABORTED

LIVE_CSS = """
#title { height: 1; background: $primary; color: $text; text-style: bold; }
#state { height: auto; max-height: 5; }  /* an abort's cause wraps, never cut */
#main { height: 1fr; }
#fields { width: 32; padding: 0 1; }
#plot { width: 1fr; }
#results { width: 1fr; display: none; padding: 0 1; }  /* a characterisation's figures, in place of the plot */
#state.aborted { background: $error 40%; }
#state.done { background: $success 40%; }
"""


class LiveApp(OverlayMixin, DynoApp):
    CSS = DynoApp.CSS + LIVE_CSS
    BINDINGS = DynoApp.BINDINGS + [
        Binding("g", "go", "GO"), Binding("p", "pause", "pause/resume"), Binding("m", "manual", "manual"),
        Binding("left_square_bracket", "jog(-1)", "release"), Binding("right_square_bracket", "jog(1)", "apply"),
        Binding("1", "plot('1')", show=False), Binding("2", "plot('2')", show=False),
        Binding("3", "plot('3')", show=False), Binding("4", "results", show=False), Binding("o", "overlay", "overlay"),
        Binding("q", "quit_safe", "quit"), Binding("r", "rearm", "re-arm"),
    ]

    def __init__(self, opts: LiveOptions | None = None) -> None:
        super().__init__()
        self.opts = opts or LiveOptions()
        self.session: LiveSession | None = None
        self.rate = RateMeter()
        self.history = History()
        self.plot_key = "1"
        self.values = None
        self._init_overlay()
        self._plotted = None
        self._plotted_t = 0.0
        self._ideal_rpm = math.nan
        self._refresh_timer = None
        self._refresh_hz = 0.0
        self._ended: bool | None = None  # the help line shown: None (not yet), False (GO ...), True (re-arm)
        self.view_results = False  # the results panel is shown in place of the plot
        self._results_shown_for = None  # the controller whose results were put up by themselves (once)

    # --- layout ------------------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        mode = f"SIM x{self.opts.speed:g} seed {self.opts.seed}" if self.opts.sim else "RIG"
        self._mode = mode
        yield Static(f" dyno live │ {mode}", id="title")
        yield Static(f" E-STOP: {ESTOP_KEYS} (always active)", id="estop")
        yield Readout("", id="state", fixed_size=False)  # an abort's cause wraps: its height follows
        with Horizontal(id="main"):
            yield Readout("", id="fields")
            yield PlotextPlot(id="plot")
            yield Readout("", id="results")
        yield bottom_lines(HELP)

    async def on_mount(self) -> None:
        from dyno.errors import DynoError

        try:
            self.session = LiveSession(self.opts)
        except DynoError as exc:  # a bad config file or run directory: say which, leave cleanly
            self.exit(return_code=2, message=f"dyno ui: error: {exc}")
            return
        self._ideal_rpm = ideal_engine_rpm(self.session.controller.engine_map)
        self.session.on_signal = lambda code: self.call_later(self._quit, code)
        # The first screen (layout, styles, the plot's first draw) is the longest the loop is ever busy:
        # draw it before the rig's clock, the poller and the watchdog start, never after (on a loaded
        # machine it stalled the loop past the 0.5 s watchdog: an abort before ARMED).
        self._show_run()
        self.refresh_values(force=True)
        self.call_after_refresh(self._start_session)

    def _start_session(self) -> None:
        if self.session.closed:
            return
        # Everything built so far (imports, maps, the screen) lives as long as the app: out of the cyclic
        # collector's sight, or each full collection walks it all while the loop waits (0.1-0.3 s measured
        # on a loaded 2-core machine: with the rest of a busy moment, past the 0.5 s watchdog).
        import gc

        gc.collect()
        gc.freeze()
        self.session.start()
        self.refresh_values(force=True)  # (starts the refresh timer at the state's rate)

    # --- refresh -------------------------------------------------------------------------------
    def refresh_values(self, force: bool = False) -> None:
        s = self.session
        if s is None:
            return
        try:
            st = self.query_one("#state", Static)
        except NoMatches:  # the app is closing: its widgets go before its interval timer stops
            return
        now = self.session.loop.time()
        self._refresh_rate(s.controller.state.value in TEST_STATES)
        self._show_help(s.finished)
        v = live_values(s.poller, s.controller, now, self.rate)
        self.values = v
        self.history.add(now - s.t0, v)
        st.update(self._state_text(v))
        st.set_class(v.state == "aborted", "aborted")
        st.set_class(v.state == "done", "done")
        self._show_fields()
        self._show_results()
        if self.overlay_requested:
            if len(s.controller.points) != self._overlay_points:
                self._start_overlay()
            elif v.state in ("settle", "measure"):
                self._overlay_prime()
        self._draw_plot()

    def _refresh_rate(self, testing: bool) -> None:
        """One interval timer at the state's rate: while nothing runs it fires at the idle rate (a timer
        that fires and returns early still wakes the loop: the idle CPU is mostly wake-ups)."""
        hz = REFRESH_HZ if testing else IDLE_REFRESH_HZ
        if hz != self._refresh_hz:
            if self._refresh_timer is not None:
                self._refresh_timer.stop()
            self._refresh_timer, self._refresh_hz = self.set_interval(1.0 / hz, self.refresh_values), hz

    def _state_text(self, v) -> Text:
        t = Text()
        t.append(f" {v.state.upper()}", style="bold")
        if v.paused and v.state not in ("done", "aborted"):
            t.append(" (PAUSED)", style="bold yellow")
        if self.session.manual:
            t.append(" MANUAL", style="bold magenta")
        s = self.session
        if v.state == "measure" and s.controller.plan.mode not in FROM_IDLE:
            t.append(f"  {measure_text(s.state_elapsed_s(), s.opts.plan)}")
        else:
            t.append(f"  {v.reason}")
        n, total, eta = s.test_progress()
        prog = progress_text(v.state, n, total, eta) if s.controller.plan.mode not in FROM_IDLE else ""
        if prog:
            t.append(f"  │ {prog}", style="bold")
        if v.state == "done" and s.controller.points:  # what a tuner reads next: the term to improve, and compare
            largest = largest_term(s.controller.points)
            if largest is not None:
                for name in (largest[0], TERM_SHORT.get(largest[0], largest[0])):  # (the short name if too wide)
                    line = (f" U95 mostly {name} ±{100 * largest[1]:.1f}/{100 * largest[2]:.1f} pp; "
                            f"{COMPARE_NOTE_SHORT}")
                    if len(line) < 80:
                        break
                t.append("\n" + line)
        disc = discard_text(s.controller.discards)
        if disc and v.state in TEST_STATES:
            t.append(f"\n {disc}", style="yellow")
        if v.state == "aborted" or v.abort_cause:
            safe = getattr(self.session.actuators, "is_safe", None)
            safe_txt = {True: "rig SAFE", False: "rig NOT SAFE", None: "safe state commanded"}[safe]
            t.append(f"\n {safe_txt}: throttle idle, engine killed, brake released", style="bold")
            t.append(f"\n cause: {v.abort_cause}: {v.abort_detail}", style="bold")
        return t

    def _show_fields(self) -> None:
        """The fields column from the last values (also between refreshes: the overlay's status)."""
        if self.values is not None:
            self.query_one("#fields", Static).update(self._fields_text(self.values))

    def _fields_text(self, v) -> Text:
        t = Text()

        def row(label: str, value: str, style: str = "") -> None:
            t.append(f"{label:<10}" if len(label) < 10 else label + " ")
            t.append(value + "\n", style=style)

        row("engine", fmt(v.rpm_primary, ".0f", " rpm"))
        row("secondary", fmt(v.rpm_secondary, ".0f", " rpm"))
        row("ratio", fmt(v.ratio, ".2f"))
        row("torque", fmt(v.torque_secondary_nm, ".2f", " N·m"))
        row("P out", fmt(v.power_out_w, ".0f", " W"))
        # with the input torque channel the engine's power is measured (T_in w_p), else the map's
        row("P engine", fmt(v.power_engine_w, ".0f", " W (T_in)" if v.power_source == "input" else " W (map)"))
        # The denominator is the map's curve at the commanded throttle (n/a without one); the efficiency
        # means something only while the test holds a steady load (never in the characterisations:
        # throttle ramps, idle, an engine cut).
        loaded = v.state in TEST_STATES and self.session.controller.plan.mode not in FROM_IDLE
        row("effic.", efficiency_text(v, loaded))
        colour, marker = temp_colour(v.rotor_temp_c, v.rotor_temp_limit_c)
        row("rotor", fmt(v.rotor_temp_c, ".0f", f"/{v.rotor_temp_limit_c:.0f} °C{marker}"), f"bold {colour}")
        u95, interval = last_point_text(self.session.controller.points)
        row("points", str(v.points) + (f"  {u95}" if u95 else ""))
        row("interval95", interval or "—")  # the last point's efficiency_interval95
        nd = len(self.session.controller.discards)
        row("discarded", f"{nd} windows" if nd != 1 else "1 window", "bold yellow" if nd else "")
        largest = largest_term(self.session.controller.points)
        row("U95 most", "—" if largest is None else
            f"{TERM_SHORT.get(largest[0], largest[0])} ±{100 * largest[1]:.1f} of {100 * largest[2]:.1f} pp")
        row("link", fmt(v.frames_per_s, ".0f", " frames/s"))
        # (each row its own label, within the column's 30 characters: 80x24 shows every row unwrapped)
        row("CRC/NACK", f"{v.crc_errors}/{v.nacks}  rejected {v.rejected_total}")
        row("lost", f"{v.events_lost} events", "bold red" if v.events_lost else "")
        row("Nano run", v.run_enable, "bold red" if v.run_enable.startswith("off") else "")
        if self.overlay_requested:
            row("overlay", self.overlay_tier or "computing…")
        return t

    def _show_results(self) -> None:
        """A characterisation plan's figures (engagement, coast-down): shown by themselves once they arrive
        (``4`` brings them back after ``1``-``3``); the controller's ``results``, as stored with the run."""
        ctrl = self.session.controller
        if not has_results(ctrl.results):
            if self.view_results:  # (a re-armed run has none yet)
                self._set_view(results=False)
            return
        if self._results_shown_for is not ctrl:
            self._results_shown_for = ctrl
            self._set_view(results=True)
        if self.view_results:
            self.query_one("#results", Static).update("\n".join(results_lines(ctrl.results)))

    def _set_view(self, results: bool) -> None:
        self.view_results = results
        self.query_one("#results").display = results
        self.query_one("#plot").display = not results
        if not results:
            self._plotted = None  # redraw the plot now that it shows again

    def action_results(self) -> None:
        if self.session is None or not has_results(self.session.controller.results):
            self.say("no results: the engagement and coast-down plans show theirs here when they end")
            return
        self._set_view(results=True)
        self._show_results()
        self.say("results of the characterisation (also in the run's report.html)")

    def _draw_plot(self) -> None:
        if self.view_results:
            return  # the plot is hidden behind the results
        w = self.query_one("#plot", PlotextPlot)
        plt = w.plt
        pts = self.session.controller.points
        key = (self.plot_key, len(pts), self.overlay_tier, self._overlay_version, self.overlay_requested,
               id(self.session.controller))
        now = time.monotonic()
        if key == self._plotted and (self.plot_key == "1" or now - self._plotted_t < PLOT_PERIOD_S):
            return  # the efficiency plot changes only with points; the others drift slowly
        self._plotted, self._plotted_t = key, now
        plt.clear_data()
        plt.clear_figure()
        if self.plot_key == "1":
            draw_efficiency(plt, pts, self.overlay_full if self.overlay_requested else None,
                            self.overlay if self.overlay_requested else None)
        elif self.plot_key == "2":
            draw_shift_curve(plt, self.history, pts, self._ideal_rpm)
        else:
            draw_time(plt, self.history)
        w.refresh()

    # --- keys ------------------------------------------------------------------------------------
    def action_estop(self) -> None:
        self.dismiss_modals()
        if self.session is not None:
            self.session.estop("operator, " + ESTOP_KEYS)
            self.say("E-STOP: rig put in its safe state")
            self.refresh_values(force=True)

    def action_go(self) -> None:
        why = self.session.go_refusal() if self.session else "starting"
        if why:
            self.say(why)
            return

        what = go_text(self.session.controller.plan)  # (what this plan moves: steps, holds, a ramp, a cut)

        def answered(yes: bool | None) -> None:
            if yes:
                self.say(self.session.go() or what[1])
            else:
                self.say("GO cancelled")

        self.push_screen(ConfirmScreen(f"Start the test?\n{what[0]}"), answered)

    def action_rearm(self) -> None:
        """Acknowledge the ended test and arm a new one (new run directory); asks first."""
        s = self.session
        why = s.rearm_refusal() if s else "starting"
        if why:
            self.say(why)
            return
        last = s.controller.aborts[-1] if s.controller.aborts else None
        ended = f"ABORTED ({last['cause']}: {last['detail']})" if last else "DONE"
        if len(ended) > 120:
            ended = ended[:119] + "…"

        def answered(yes: bool | None) -> None:
            if not yes:
                self.say("re-arm cancelled")
                return
            new_dir, msg = self.session.rearm()  # the rig is checked again: it may have changed meanwhile
            self.say(msg)
            if new_dir is not None:
                self._plotted = None
                self._show_run()
                self.refresh_values(force=True)

        self.push_screen(ConfirmScreen(f"Acknowledge: {ended}.\nRe-arm? A new run directory is started (this run "
                                       "keeps its record). Nothing moves: start the engine, then GO."), answered)

    def _show_run(self) -> None:
        """The title: mode and the run directory being written (its start cut, to fit)."""
        run = str(self.session.ctx.writer.run_dir)
        head = f" dyno live │ {self._mode} │ run "
        room = max(10, (self.size.width or 80) - len(head) - 1)
        self.query_one("#title", Static).update(head + (run if len(run) <= room else "…" + run[-room + 1:]))

    def _show_help(self, ended: bool) -> None:
        if ended != self._ended:
            self._ended = ended
            self.query_one("#help", Static).update(HELP_ENDED if ended else HELP)

    def action_pause(self) -> None:
        self.say(self.session.toggle_pause())

    def action_manual(self) -> None:
        if self.session.manual:
            self.say(self.session.set_manual(False))
            return
        if self.session.finished:
            self.say("test finished: the rig stays in its safe state")
            return

        def answered(yes: bool | None) -> None:
            self.say(self.session.set_manual(True) if yes else "manual mode cancelled")

        self.push_screen(ConfirmScreen("Manual mode: stepping pauses and [ / ] MOVE THE BRAKE actuator "
                                       f"({self.opts.jog_s:g} s per press).\nEnable?"), answered)

    def action_jog(self, direction: int) -> None:
        why = self.session.jog(direction)
        self.say(why or ("jog: apply" if direction > 0 else "jog: release"))

    def action_plot(self, key: str) -> None:
        self.plot_key = key
        if self.view_results:
            self._set_view(results=False)
        self._plotted = None
        self.say(f"plot: {PLOTS[key]}")
        self._draw_plot()

    async def action_quit_safe(self) -> None:
        if self.session is None or self.session.finished:
            await self._quit()
            return

        def answered(yes: bool | None) -> None:
            if yes:
                self.run_worker(self._quit(), exclusive=True, group="quit")

        self.push_screen(ConfirmScreen("Quit? The rig is put in its safe state first."), answered)

    async def _quit(self, code: int = 0) -> None:
        if self.session is not None:
            await self.session.close("operator quit" if not code else "signal")
        self.exit(return_code=code)

    async def on_unmount(self) -> None:
        if self.overlay_service is not None:  # drop queued points, stop the running solve at its next step
            self.overlay_service.close()
        if self.session is not None:  # any other way out: still safe state first
            await self.session.close("UI closed")


def main(opts: LiveOptions) -> int:
    app = LiveApp(opts)
    app.run()
    return app.return_code or 0
