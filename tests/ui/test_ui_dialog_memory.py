"""A dismissed confirmation dialog is freed: the operator's GO and re-arm dialogs must not add up over a long
session (the UI soak's RSS grew with every test, docs/safety.md "Soak").

Textual's ``StylesCache.get_inner_outer`` is an ``lru_cache`` on a method: its keys held every dismissed
dialog's widgets and their rendered lines (~180 KB a dialog at 120x40) until 1,024 entries had filled;
``ConfirmScreen`` empties it when it goes (:func:`dyno.ui.common.forget_removed_widgets`).
"""

from __future__ import annotations

import asyncio
import gc
import tracemalloc

from textual.widgets import Static

from dyno.ui.common import ConfirmScreen, DynoApp, bottom_lines

SIZE = (120, 40)  # the UI soak's terminal
DIALOGS = 24  # a dozen tests' worth (GO and re-arm each ask)
WARM = 4  # dialogs before measuring: Textual's own bounded caches fill first


class Host(DynoApp):
    def compose(self):
        yield Static(" dyno live │ SIM", id="title")
        yield Static(" E-STOP: space / Ctrl+C (always active)", id="estop")
        yield bottom_lines("g GO  q quit")


def _live_styles_caches() -> int:
    from textual._styles_cache import StylesCache

    return sum(type(o) is StylesCache for o in gc.get_objects())


def test_dismissed_confirm_dialogs_are_freed():
    answers = []

    async def scenario():
        app = Host()
        async with app.run_test(size=SIZE) as pilot:
            traced = {}
            live = {}
            for k in range(1, DIALOGS + 1):
                app.push_screen(ConfirmScreen(f"Start the test?\nDialog {k}: throttle goes to FULL."),
                                answers.append)
                await pilot.pause(0.05)
                assert isinstance(app.screen, ConfirmScreen)
                await pilot.press("y" if k % 2 else "n")
                await pilot.pause(0.05)
                assert not isinstance(app.screen, ConfirmScreen)
                gc.collect()
                if k == WARM:
                    tracemalloc.start(1)
                if k in (WARM + 5, DIALOGS):
                    traced[k] = tracemalloc.get_traced_memory()[0]
                    live[k] = _live_styles_caches()
            tracemalloc.stop()
            return traced, live

    traced, live = asyncio.run(scenario())
    assert answers == [bool(k % 2) for k in range(1, DIALOGS + 1)]
    # no dialog's widgets are left: as many StylesCaches at the end as after the first 9 dialogs (before the fix: +4 a dialog)
    assert live[DIALOGS] == live[WARM + 5], live
    # and the Python heap stays put: 15 more dialogs within 300 KB (before the fix: ~2.7 MB, ~180 KB a dialog)
    grown = traced[DIALOGS] - traced[WARM + 5]
    assert grown < 300_000, f"{grown / 1e3:.0f} KB over {DIALOGS - WARM - 5} dialogs"
