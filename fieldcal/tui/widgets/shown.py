"""What a widget shows is changed only when it changes, and the screen is laid out again only
where a widget's size can follow its text.

Textual's ``Static.update`` re-lays-out the whole screen by default (``layout=True``): done for
every reading, ten times a second, that was most of the TUI's CPU. A widget whose size the CSS
fixes (one row of the live panel, the job line) is only repainted.
"""
from __future__ import annotations

from textual.widgets import Static


def show(widget: Static, content, fixed_size: bool = False) -> None:
    """Show ``content`` (a str or Rich ``Text``) on ``widget`` unless it already does.
    ``fixed_size``: the widget's size is set by the CSS, never by its content."""
    if widget.content == content:
        return
    widget.update(content, layout=not fixed_size)
