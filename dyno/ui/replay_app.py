"""The replay viewer (``dyno replay RUN [RUN...]``): points, raw streams, re-processing, overlays, exports.

Thin over :mod:`dyno.ui.replay_model`.  No rig is attached: the E-STOP keys
are bound as on every dyno screen but only say so.
"""

from __future__ import annotations

import math
from pathlib import Path

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen
from textual.widgets import DataTable, Input, Static
from textual_plotext import PlotextPlot

from dyno.ui.common import DynoApp, EstopSafeInput, bottom_lines
from dyno.ui.replay_model import (ReplaySet, compare_with_first, efficiency_series, export_csv, export_png, finite,
                                  ideal_rpm_for, point_streams, predicted_shift_series, shift_series)

HELP = "↑↓ point  n run  1-4 plot  c cal  e map  x CSV  s PNG  q quit │ ^C E-STOP"
COLOURS = ("cyan", "magenta", "yellow", "green", "red", "blue")
PLOTS = {"1": "efficiency (all runs)", "2": "shift curve (all runs)", "3": "raw streams of the point",
         "4": "efficiency difference from run 1 (95 %)"}

REPLAY_CSS = """
#title { height: 1; background: $primary; color: $text; text-style: bold; }
#runinfo { height: 1; }
#main { height: 1fr; }
#points { width: 38; }
#plot { width: 1fr; }
PathScreen { align: center middle; }
PathScreen > Vertical { width: 70; height: auto; border: heavy $accent; background: $surface; padding: 0 1; }
"""


class PathScreen(ModalScreen[str | None]):
    """Ask for a file path (Enter accepts, Escape cancels)."""

    BINDINGS = [Binding("escape", "cancel", "cancel")]

    def __init__(self, prompt: str) -> None:
        super().__init__()
        self.prompt = prompt

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Static(self.prompt)
            yield EstopSafeInput(placeholder="path (Enter = use, Esc = cancel)", id="path")

    def on_mount(self) -> None:
        self.query_one(Input).focus()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.dismiss(event.value.strip() or None)

    def action_cancel(self) -> None:
        self.dismiss(None)


class ReplayApp(DynoApp):
    CSS = DynoApp.CSS + REPLAY_CSS
    BINDINGS = DynoApp.BINDINGS + [
        Binding("n", "next_run", "next run"), Binding("1", "plot('1')", show=False),
        Binding("2", "plot('2')", show=False), Binding("3", "plot('3')", show=False),
        Binding("4", "plot('4')", show=False),
        Binding("c", "reprocess('calibration')", "calibration"), Binding("e", "reprocess('engine map')", "map"),
        Binding("x", "export_csv", "CSV"), Binding("s", "export_png", "PNG"), Binding("q", "quit_safe", "quit"),
    ]

    def __init__(self, run_dirs, calibration_path=None, engine_map_path=None, png_path=None) -> None:
        super().__init__()
        self.run_dirs = [Path(d) for d in run_dirs]
        self.calibration_path = calibration_path
        self.engine_map_path = engine_map_path
        self.png_path = Path(png_path) if png_path else self.run_dirs[0] / "export" / "replay.png"
        self.rs: ReplaySet | None = None
        self.current = 0
        self.plot_key = "1"

    def compose(self) -> ComposeResult:
        yield Static(f" dyno replay │ {len(self.run_dirs)} run(s)", id="title")
        yield Static("", id="runinfo")
        with Horizontal(id="main"):
            yield DataTable(id="points", cursor_type="row", zebra_stripes=True)
            yield PlotextPlot(id="plot")
        yield bottom_lines(HELP)

    def on_mount(self) -> None:
        from dyno.errors import DynoError

        try:
            self.rs = ReplaySet.load(self.run_dirs, self.calibration_path, self.engine_map_path)
        except DynoError as exc:
            self.exit(return_code=2, message=f"dyno replay: error: {exc}")
            return
        self._ideal = ideal_rpm_for(self.rs.runs[0])
        self._predicted: dict = {}  # run_dir -> predicted shift curve (from the run's tune)
        self.run_worker(self._predict_work, thread=True, exclusive=False)
        table = self.query_one("#points", DataTable)
        table.add_columns("#", "n_s", "n_e", "T N·m", "eff %", "±")
        self._fill_table()
        table.focus()

    # --- view -----------------------------------------------------------------------------------
    @property
    def current_run(self):
        # not ``run``: that would shadow Textual's App.run() and crash ``dyno replay RUN`` at start
        return self.rs.runs[self.current]

    def _fill_table(self) -> None:
        table = self.query_one("#points", DataTable)
        table.clear()
        for i, p in enumerate(self.current_run.points):
            def f(k, spec, scale=1.0):
                v = p.get(k)
                return format(v * scale, spec) if finite(v) else "—"
            mark = "" if p.get("valid", True) else "!"
            table.add_row(f"{p.get('index', i)}{mark}", f("rpm_secondary", ".0f"), f("rpm_primary", ".0f"),
                          f("torque_secondary_nm", ".2f"), f("efficiency", ".1f", 100), f("efficiency_sem", ".1f", 100),
                          key=str(i))
        rr = self.current_run
        stop = rr.result.get("stop") or {}
        counts = rr.run.streams.counts()
        self.query_one("#runinfo", Static).update(
            f" run {self.current + 1}/{len(self.rs.runs)}: {rr.label} │ {len(rr.points)} points │ "
            f"{stop.get('exit_status', 'no stop doc')} │ edges {counts['primary_edges']}/{counts['secondary_edges']} "
            f"adc {counts['adc_samples']}")
        self._draw()

    def on_data_table_row_highlighted(self, event: DataTable.RowHighlighted) -> None:
        if self.plot_key == "3":
            self._draw()

    def _selected_point(self):
        table = self.query_one("#points", DataTable)
        pts = self.current_run.points
        if not pts:
            return None
        return pts[min(max(table.cursor_row, 0), len(pts) - 1)]

    def _draw(self) -> None:
        w = self.query_one("#plot", PlotextPlot)
        plt = w.plt
        plt.clear_data()
        plt.clear_figure()
        if self.plot_key == "1":
            plt.title("efficiency vs secondary rpm")
            for k, rr in enumerate(self.rs.runs):
                x, y, e = efficiency_series(rr.points)
                if x:
                    plt.error(x, y, yerr=e, color=COLOURS[k % len(COLOURS)], label=rr.label[:18])
            plt.xlabel("secondary rpm")
        elif self.plot_key == "2":
            plt.title(f"shift curve; ideal {self._ideal:.0f} rpm")
            for k, rr in enumerate(self.rs.runs):
                x, y = shift_series(rr.points)
                if x:
                    plt.plot(x, y, marker="dot", color=COLOURS[k % len(COLOURS)], label=rr.label[:18])
            for k, rr in enumerate(self.rs.runs):
                pred = self._predicted.get(str(rr.run_dir))
                if pred:
                    plt.plot(pred[0], pred[1], color=COLOURS[k % len(COLOURS)], label="predicted (tune)")
            if math.isfinite(self._ideal):
                plt.hline(self._ideal, color="green")
            plt.xlabel("secondary rpm")
        elif self.plot_key == "4":
            self._draw_difference(plt)
        else:
            p = self._selected_point()
            if p is not None and "t_start_us" in p:
                d = point_streams(self.current_run.run, p)
                plt.title(f"point {p.get('index')}: rpm (left), ADC (right)")
                if d["primary_t_s"]:
                    plt.scatter(d["primary_t_s"], d["primary_rpm"], marker="dot", color="yellow", label="engine")
                if d["secondary_t_s"]:
                    plt.scatter(d["secondary_t_s"], d["secondary_rpm"], marker="dot", color="cyan",
                                label="secondary")
                if d["adc_t_s"]:
                    plt.plot(d["adc_t_s"], d["adc_counts"], color="magenta", yside="right", label="ADC")
                plt.vline(0.0, color="gray")
                plt.vline(d["window_s"], color="gray")
                plt.xlabel("s from the point's start")
            else:
                plt.title("no point selected")
        w.refresh()

    def _draw_difference(self, plt) -> None:
        """This run's efficiency minus run 1's on a common rpm grid, with the difference's stated 95 %
        uncertainty as the band (statistics, each run's own tare and what systematics do not cancel:
        :mod:`dyno.library.compare`); ±1.96 s.e. where a run states none (docs/library.md)."""
        if self.current == 0:
            plt.title("difference: run 1 is the reference; n = next run")
            return
        try:
            res = compare_with_first(self.rs, self.current)
        except ValueError as exc:
            plt.title(f"no difference: {exc}"[:70])
            return
        d = res["differences"][0]
        q = d["quantities"]["efficiency"]
        stated = q.get("difference_u95") is not None and q.get("significant_u95") is not None
        half = q["difference_u95"] if stated else [None if s is None else 1.96 * s for s in q["sem"]]
        half = [h if h is not None else (None if s is None else 1.96 * s) for h, s in zip(half, q["sem"])]
        rows = [(g, v * 100, h * 100, sig) for g, v, h, sig in
                zip(res["grid_rpm_secondary"], q["difference"], half,
                    q["significant_u95"] if stated else q["significant"]) if v is not None and h is not None]
        if not rows:
            plt.title("no difference: no common grid speed")
            return
        x = [r[0] for r in rows]
        plt.plot(x, [r[2] for r in rows], color="gray")
        plt.plot(x, [-r[2] for r in rows], color="gray", label="±U95" if stated else "±1.96 s.e.")
        plt.hline(0.0, color="gray")
        sig = [r for r in rows if r[3]]
        if sig:
            plt.scatter([r[0] for r in sig], [r[1] for r in sig], marker="dot", color="red", label="significant")
        plt.scatter([r[0] for r in rows if not r[3]], [r[1] for r in rows if not r[3]], marker="dot", color="cyan")
        plt.title(f"Δeff % vs run 1: {len(sig)}/{len(rows)} sig. 95 %")  # short: plotext drops a long one
        plt.xlabel("secondary rpm")
        tune = ", ".join(f"{t['key']} {t['from']}→{t['to']}" for t in d["tune_diff"] if t["key"] != "notes")
        self.say(f"tune: {tune or 'same as run 1'}")

    def _predict_work(self) -> None:
        """Predicted shift curves from each run's stored tune, off the UI thread."""
        for rr in list(self.rs.runs):
            pred = predicted_shift_series(rr.run_dir)
            if pred:
                self._predicted[str(rr.run_dir)] = pred
        if self._predicted:
            self.call_from_thread(self._draw)

    # --- keys ------------------------------------------------------------------------------------
    def action_plot(self, key: str) -> None:
        self.plot_key = key
        self.say(f"plot: {PLOTS[key]}")
        self._draw()

    def action_next_run(self) -> None:
        self.current = (self.current + 1) % len(self.rs.runs)
        self._fill_table()

    def action_reprocess(self, what: str) -> None:
        def answered(path: str | None) -> None:
            if not path:
                self.say("re-processing cancelled")
                return
            from dyno.errors import DynoError

            try:
                if what == "calibration":
                    self.rs.reprocess(self.current, calibration_path=Path(path))
                else:
                    self.rs.reprocess(self.current, engine_map_path=Path(path))
            except (DynoError, OSError, ValueError) as exc:
                self.say(f"not re-processed: {exc}")
                return
            self.say(f"re-processed with {what} {path}")
            self._fill_table()

        self.push_screen(PathScreen(f"Re-process run {self.current_run.run_dir.name} with which {what} file?"), answered)

    def action_export_csv(self) -> None:
        files = export_csv(self.current_run)
        self.say(f"CSV: {len(files)} files in {files[0].parent}")

    def action_export_png(self) -> None:
        self.say("writing PNG…")
        self.run_worker(self._png_work, thread=True, exclusive=True, group="png")

    def _png_work(self) -> None:
        # matplotlib takes ~0.5 s to import and draw: off the UI thread.
        path = export_png(self.rs, self.png_path, self._ideal)
        self.call_from_thread(self.say, f"PNG: {path}")


def main(args) -> int:
    """Entry point from :mod:`dyno.cli.replay_cmd` (``args.run``, ``args.calibration``, ``args.engine_map``)."""
    app = ReplayApp(args.run, getattr(args, "calibration", None), getattr(args, "engine_map", None))
    app.run()
    return app.return_code or 0
