"""The procedure screen's event log: a RichLog that stays at its end when its height changes.

RichLog scrolls to its end when a line is written. When the banner above it grows a line (a
heading-only step's warning, a confirmation), the log gets shorter after that scroll, and its
last lines would stay hidden until the next event: the operator would not see the newest one.
"""
from __future__ import annotations

from textual.events import Resize
from textual.widgets import RichLog


class EventLog(RichLog):
    def write_lines(self, lines) -> None:
        """Write ``lines`` and scroll to the end at once, in the frame that shows them: RichLog's
        own scroll after each line waits for the next refresh, which cost a second and a third
        repaint of the whole log (and its scrollbar) for every batch. Before the log's size is
        known the writes wait, and on_resize scrolls once they are made."""
        for line in lines:
            self.write(line, scroll_end=False)
        if self.auto_scroll:
            self.scroll_end(animate=False, immediate=True, x_axis=False)

    def on_resize(self, event: Resize) -> None:  # (RichLog's own on_resize runs as well)
        if self.auto_scroll:
            self.scroll_end(animate=False, immediate=False, x_axis=False)
