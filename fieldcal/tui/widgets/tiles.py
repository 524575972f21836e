"""One tile per position, QGroundControl style: grey to do, yellow in progress, green done,
red skipped or misplaced; and a symbol each (✓ done, – skipped, ▶ current, · to do), so that
the states read without colour."""
from __future__ import annotations

import math

from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.widgets import Static

from fieldcal.tui.view import ACTIVE, DONE, SKIPPED, SYMBOLS, TODO, WRONG

STATES = (TODO, ACTIVE, DONE, SKIPPED, WRONG)
WITH_GAPS = 19  # 4 cells per tile fit 19 in 78 columns
NARROW = 26  # 3 cells per tile (no gap) fit 26


def tile_rows(n: int) -> tuple[int, bool]:
    """(tiles per row, narrow) for ``n`` positions within 78 columns: one row while they fit,
    narrow tiles rather than a second row, then rows as even as they can be (a planned
    procedure's 30 positions: two rows of 15)."""
    if n <= WITH_GAPS:
        return max(n, 1), False
    if n <= NARROW:
        return n, True
    rows = math.ceil(n / WITH_GAPS)
    return math.ceil(n / rows), False


class PositionTiles(Vertical):
    """``update(states)`` with one state per position (fieldcal.tui.view TODO, ACTIVE, ...)."""

    DEFAULT_CSS = """
    PositionTiles { height: auto; }
    PositionTiles > .tile-row { height: 1; }
    """

    def __init__(self, ids: list[int], **kw) -> None:
        super().__init__(**kw)
        self.ids = ids
        self._states = [TODO] * len(ids)
        self.per_row, self.narrow = tile_rows(len(ids))

    def compose(self) -> ComposeResult:
        for start in range(0, len(self.ids), self.per_row):
            with Horizontal(classes="tile-row"):
                for i in range(start, min(start + self.per_row, len(self.ids))):
                    tile = Static(self.label(i, TODO), classes=f"tile {TODO}", id=f"tile-{i}")
                    if self.narrow:
                        tile.add_class("narrow")
                    yield tile

    def update(self, states: list[str]) -> None:
        for i, state in enumerate(states):
            if state != self._states[i]:
                tile = self.query_one(f"#tile-{i}", Static)
                # One change of classes: each restyles the tile (Textual applies the CSS at once).
                tile.set_classes(tile.classes - set(STATES) | {state})
                tile.update(self.label(i, state))
        self._states = list(states)

    def label(self, i: int, state: str) -> str:
        return f"{SYMBOLS[state]}{self.ids[i]:>2}"
