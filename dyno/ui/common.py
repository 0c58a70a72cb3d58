"""Pieces every dyno screen shares: the E-STOP keys, the confirmation dialog, the help line.

Layout rules (80x24 over SSH, keyboard only): one help line of keys at the
bottom of every screen, no mouse-only controls, and colours that only repeat
what the text already says (a monochrome terminal loses nothing but tint;
Textual downgrades truecolor to 256/16 colours by itself).
"""

from __future__ import annotations

from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, Static

ESTOP_KEYS = "space / Ctrl+C"
ESTOP_KEY_NAMES = ("space", "ctrl+c")

BASE_CSS = """
Screen { layout: vertical; }
#estop { height: 1; background: $error; color: $text; text-style: bold; }
#bottom { dock: bottom; height: 2; }
#help { height: 1; background: $panel; color: $text; }
#msg { height: 1; color: $warning; }
ConfirmScreen { align: center middle; }
ConfirmScreen > Vertical { width: 60; height: auto; border: heavy $warning; background: $surface; padding: 0 1; }
"""


def bottom_lines(help_text: str):
    """The message line and the help line of keys, docked at the bottom of a screen."""
    return Vertical(Static("", id="msg"), Static(help_text, id="help"), id="bottom")


def estop_bindings() -> list[Binding]:
    # priority=True: the keys reach the app before any widget (an Input, a modal) can take them.
    # Ctrl+C replaces Textual's default "help quit"; Ctrl+Q replaces its plain quit.
    return [Binding("space", "estop", "E-STOP", priority=True),
            Binding("ctrl+c", "estop", "E-STOP", priority=True, show=False),
            Binding("ctrl+q", "quit_safe", "quit", priority=True, show=False)]


class EstopSafeInput(Input):
    """A text field that never takes an E-STOP key.

    Textual drops *every* ancestor binding, priority ones included, for a key the
    focused Input says it consumes (``Screen._binding_chain``): a plain Input would eat
    the space bar.  This one declines the E-STOP keys, so they reach the app's priority
    bindings whatever is focused.  (No field here needs a space: numbers and lists.)
    """

    def check_consume_key(self, key: str, character: str | None) -> bool:
        if key in ESTOP_KEY_NAMES:
            return False
        if character is not None and character.isprintable() and self.restrict is not None:
            import re

            if not re.fullmatch(self.restrict, character):
                return False  # not for this field (e.g. "c" in a number): the screen's key acts
        return super().check_consume_key(key, character)


class Readout(Static):
    """A Static for values refreshed a few times a second, at the least cost.

    An unchanged text is not redrawn at all; a changed one repaints this widget only,
    without a layout pass of the screen (Static's default, the larger part of a refresh),
    unless its height may change: ``fixed_size=False`` (height auto) lays out again
    when a line is added or removed, or a line too long for the width (it wraps) changes.
    """

    def __init__(self, content="", *, fixed_size: bool = True, **kwargs) -> None:
        super().__init__(content, **kwargs)
        self._fixed = fixed_size
        self._shown = None
        self._shape = None

    def update(self, content="", *, layout: bool | None = None) -> None:
        if content == self._shown and type(content) is type(self._shown):
            return
        self._shown = content
        if layout is None:
            layout = False
            if not self._fixed:
                plain = getattr(content, "plain", None)
                plain = str(content) if plain is None else plain
                width = max(1, self.content_size.width or 80)
                shape = tuple(line if len(line) >= width else 1 for line in plain.split("\n"))
                layout, self._shape = shape != self._shape, shape
        super().update(content, layout=layout)


class ConfirmScreen(ModalScreen[bool]):
    """y / Enter confirms, n / Escape declines.  The E-STOP keys still work (app priority bindings)."""

    BINDINGS = [Binding("y", "answer(True)", "yes"), Binding("enter", "answer(True)", "yes", show=False),
                Binding("n", "answer(False)", "no"), Binding("escape", "answer(False)", "no", show=False)]

    def __init__(self, question: str) -> None:
        super().__init__()
        self.question = question

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Static(self.question, id="question")
            yield Static("[b]y[/b] / Enter = yes     [b]n[/b] / Esc = no", id="answer")

    def action_answer(self, yes: bool) -> None:
        self.dismiss(yes)

    def on_unmount(self) -> None:
        forget_removed_widgets()


def forget_removed_widgets() -> None:
    """Let the widgets of a screen that has gone be freed: empty Textual's background-style cache.

    ``textual._styles_cache.StylesCache.get_inner_outer`` is an ``lru_cache`` (1,024 entries) on a *method*:
    each key holds the widget's ``StylesCache``, and with it every line the widget last rendered.  A
    dismissed dialog's widgets stay alive through it (4 per ``ConfirmScreen``), so memory grows with every
    dialog until the cache's 1,024 entries are full (docs/safety.md, "Soak").  The entries are two ``Style`` objects,
    recomputed on the next draw.  A Textual without that cache (a later version): nothing to do.
    """
    try:
        from textual._styles_cache import StylesCache

        StylesCache.get_inner_outer.cache_clear()
    except (ImportError, AttributeError):  # pragma: no cover - another Textual
        pass


def detach_terminal() -> None:
    """The terminal went (SIGHUP): point stdin, stdout and stderr at /dev/null, from the signal handler.

    Textual's output thread dies on the first write to a hung-up terminal (EIO); its queue then fills and
    the app's shut-down waits on it for ever (``dyno calibrate`` stayed behind).  Writes to /dev/null
    succeed and reads see end of file, so the app ends as if the operator had quit.  Every descriptor on
    a terminal is replaced, the hung-up one (its ioctl says EIO) and one that still answers (the signal can
    come before the pty is gone: the soak of docs/safety.md saw it); a pipe or a file is kept (tests).
    """
    import errno
    import os
    import termios

    gone = []
    for k in (0, 1, 2):
        try:
            termios.tcgetattr(k)
            gone.append(k)  # a terminal, still answering: going
        except termios.error as exc:
            if exc.args and exc.args[0] == errno.EIO:
                gone.append(k)
        except (OSError, ValueError):
            pass
    if not gone:
        return
    try:
        fd = os.open(os.devnull, os.O_RDWR)
    except OSError:
        return
    for k in gone:
        try:
            os.dup2(fd, k)
        except OSError:
            pass
    os.close(fd)


def exit_after(code: int, grace_s: float) -> None:
    """End the process with ``code`` in ``grace_s`` unless it has ended by then (a daemon thread): the
    backstop for an app whose shut-down still waits on something after the safe state."""
    import os
    import threading
    import time

    def later() -> None:
        time.sleep(grace_s)
        os._exit(code)

    threading.Thread(target=later, name="dyno-exit-grace", daemon=True).start()


class DynoApp(App):
    """Base: E-STOP everywhere, a message line, safe quit."""

    CSS = BASE_CSS
    BINDINGS = estop_bindings()
    ENABLE_COMMAND_PALETTE = False  # Ctrl+P would open a mouse-oriented palette over the E-STOP banner

    def say(self, text: str) -> None:
        try:
            self.query_one("#msg", Static).update(text)
        except Exception:  # during start-up/shut-down the line may not exist
            pass

    def dismiss_modals(self) -> None:
        """Close any open confirmation (an E-STOP cancels whatever was being confirmed)."""
        for _ in range(len(self.screen_stack)):
            if not isinstance(self.screen, ModalScreen):
                break
            self.screen.dismiss(False)

    def action_estop(self) -> None:  # overridden where there is a rig
        self.say("E-STOP: no rig is attached to this screen")

    async def action_quit_safe(self) -> None:
        self.exit(return_code=0)
