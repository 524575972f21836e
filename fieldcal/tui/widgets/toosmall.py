"""A notice over the whole screen while the terminal is smaller than the screens are laid out
for (the app sets the class ``-too-small`` on itself; the CSS is in app.tcss)."""
from __future__ import annotations

from textual.widgets import Static

MIN_COLUMNS, MIN_ROWS = 80, 24


def too_small_text(columns: int, rows: int) -> str:
    return (f"The terminal is {columns}×{rows}: fieldcal needs at least {MIN_COLUMNS}×{MIN_ROWS}.\n"
            "Enlarge the window; a run goes on meanwhile.")


class TooSmall(Static):
    DEFAULT_CSS = "TooSmall { display: none; }"  # hidden also where app.tcss is not loaded

    def __init__(self) -> None:
        super().__init__("", id="too-small")

    def on_resize(self) -> None:
        size = self.app.size
        self.update(too_small_text(size.width, size.height))
