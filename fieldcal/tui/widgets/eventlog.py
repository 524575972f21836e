"""The procedure screen's event log: a RichLog that stays at its end when its height changes.

RichLog scrolls to its end when a line is written. When the banner above it grows a line (a
heading-only step's warning, a confirmation), the log gets shorter after that scroll, and its
last lines would stay hidden until the next event: the operator would not see the newest one.
"""
from __future__ import annotations

from textual.events import Resize
from textual.widgets import RichLog


class EventLog(RichLog):
    def on_resize(self, event: Resize) -> None:  # (RichLog's own on_resize runs as well)
        if self.auto_scroll:
            self.scroll_end(animate=False, immediate=False, x_axis=False)
