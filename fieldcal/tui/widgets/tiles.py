"""One tile per position, QGroundControl style: grey to do, yellow in progress, green done,
red skipped or misplaced; and a symbol each (✓ done, – skipped, ▶ current, · to do), so that
the states read without colour."""
from __future__ import annotations

from textual.app import ComposeResult
from textual.containers import Horizontal
from textual.widgets import Static

from fieldcal.tui.view import ACTIVE, DONE, SKIPPED, SYMBOLS, TODO, WRONG

STATES = (TODO, ACTIVE, DONE, SKIPPED, WRONG)


class PositionTiles(Horizontal):
    """``update(states)`` with one state per position (fieldcal.tui.view TODO, ACTIVE, ...)."""

    def __init__(self, ids: list[int], **kw) -> None:
        super().__init__(**kw)
        self.ids = ids
        self._states = [TODO] * len(ids)
        self.narrow = len(ids) > 19  # 4 cells per tile fit 19 in 78 columns; else 3 (no gap)

    def compose(self) -> ComposeResult:
        for i in range(len(self.ids)):
            tile = Static(self.label(i, TODO), classes=f"tile {TODO}", id=f"tile-{i}")
            if self.narrow:
                tile.add_class("narrow")
            yield tile

    def update(self, states: list[str]) -> None:
        for i, state in enumerate(states):
            if state != self._states[i]:
                tile = self.query_one(f"#tile-{i}", Static)
                tile.remove_class(*STATES)
                tile.add_class(state)
                tile.update(self.label(i, state))
        self._states = list(states)

    def label(self, i: int, state: str) -> str:
        return f"{SYMBOLS[state]}{self.ids[i]:>2}"
