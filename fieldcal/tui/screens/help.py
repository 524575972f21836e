"""The key help, over whatever screen is showing."""
from __future__ import annotations

from typing import ClassVar

from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Static

SIM_KEYS = """\
r   ready: the unit is in place (the simulator carries it there); after a
    wrong placement, the simulator corrects it
d   redo this step from the placement
s   skip this position (the solve uses the others)
a   abort: stop the run, the session is kept
b   bump the fixture (simulator): a dwell in progress restarts
w   place the unit in a wrong position on purpose (simulator)
v   the results, once the run has ended; Esc there comes back here
?   this help          q   quit (an unfinished session can be resumed)"""

LIVE_KEYS = """\
r   ready: the unit is in place (place it as the screen shows, then r)
d   redo this step from the placement
s   skip this position (the solve uses the others)
a   abort: stop the run (the table stops), the session is kept
v   the results, once the run has ended; Esc there comes back here
?   this help          q   quit (the table stops; the session is kept)"""

REPLAY_KEYS = """\
A replay applies the operator actions recorded in the session, at the
recorded samples; the operator keys are ignored.

v   the results, once the replay has ended; Esc there comes back here
?   this help          q   quit"""


SETUP_KEYS = """\
Choose the device config (or type the path of one), the port, the procedure
and the station, then start.

Tab, shift+Tab   next, previous field
Enter            start (in a text field)     ctrl+s   start (anywhere)
Esc              quit                        q        quit (outside a text field)
?                this help (outside a text field)"""


class HelpScreen(ModalScreen):
    CSS_PATH = "help.tcss"
    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape,question_mark,q", "dismiss", "close", show=False)]

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
