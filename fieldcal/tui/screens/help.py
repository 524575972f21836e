"""The key help, over whatever screen is showing."""
from __future__ import annotations

from typing import ClassVar

from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Static

from fieldcal.tui.keys import LIVE_KEYS, REPLAY_KEYS, SETUP_KEYS, SIM_KEYS

class HelpScreen(ModalScreen):
    CSS_PATH = "help.tcss"
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("escape,question_mark,q", "dismiss", "close", show=False),
        # A modal screen keeps the app's ctrl+c (no priority key, so that a text field can copy)
        # from reaching the app: here it asks to quit, as over the run.
        Binding("ctrl+c", "app.request_quit", "quit", show=False),
    ]

    def __init__(self, mode: str) -> None:
        """``mode``: "setup", or the source's "sim", "live" or "replay"."""
        super().__init__()
        self.mode = mode

    def compose(self) -> ComposeResult:
        with Vertical(id="help"):
            yield Static({"replay": REPLAY_KEYS, "live": LIVE_KEYS, "setup": SETUP_KEYS}.get(self.mode, SIM_KEYS),
                         id="help-text")
            yield Static("Esc, ? or q closes this", id="help-close")

    def action_dismiss(self) -> None:
        self.dismiss()
