"""Residual per position as a small bar list (two columns), in the operator's units."""
from __future__ import annotations

from rich.text import Text

from fieldcal.residuals import per_position
from fieldcal.tui.widgets.bars import bar, signed_bar

__all__ = ["per_position", "residual_bars"]  # per_position: where the screens found it


def residual_bars(sol, columns: int = 2, bar_width: int = 10) -> Text:
    rows, unit = per_position(sol)
    scale = max((abs(v) for _, v, _ in rows), default=0.0)
    multi = any(not signed for _, _, signed in rows)
    cells = []
    for label, value, signed in rows:
        cell = Text(f"{label:>6} ")
        cell.append(f"{value:+9.3g} " if signed else f"{value:9.3g} ")
        if signed:
            cell.append_text(signed_bar(value, scale, bar_width))
        else:
            cell.append_text(bar(value / scale if scale else 0.0, bar_width, style="cyan", empty_style=""))
        cells.append(cell)
    head = Text(f"residual, RMS per position ({unit})" if multi else f"residual per position ({unit})",
                style="bold")
    lines = [head]
    per_column = -(-len(cells) // columns)
    for r in range(per_column):
        line = Text()
        for c in range(columns):
            i = c * per_column + r
            if i < len(cells):
                if c:
                    line.append("   ")
                line.append_text(cells[i])
        lines.append(line)
    return Text("\n").join(lines)
