"""Residual per position as a small bar list (two columns), in the operator's units."""
from __future__ import annotations

import re

import numpy as np
from rich.text import Text

from fieldcal.tui.widgets.bars import bar, signed_bar
from fieldcal.units import display_scale, param_unit

_POSITION = re.compile(r"position (\d+)")


def per_position(sol) -> tuple[list[tuple[str, float, bool]], str]:
    """[(label, value, signed)], unit: each position's residual (signed when it has one
    equation, else the RMS of its equations), or each average's for a classic solution."""
    scale = display_scale(sol.kind, sol.residual_unit, 0)
    unit = param_unit(sol.kind, sol.residual_unit, 0)
    residuals = np.asarray(sol.residuals, dtype=float) * scale
    labels = getattr(sol, "residual_labels", None)
    if labels is None:  # classic least squares: (n, 3) per average
        rows = residuals.reshape(len(residuals), -1)
        return [(f"avg {i + 1}", float(np.sqrt(np.mean(r**2))), False) for i, r in enumerate(rows)], unit
    groups: dict[str, list[float]] = {}
    for label, value in zip(labels, residuals):
        m = _POSITION.search(label)
        groups.setdefault(f"pos {m.group(1)}" if m else label[:6], []).append(float(value))
    out = []
    for label, values in groups.items():
        if len(values) == 1:
            out.append((label, values[0], True))
        else:
            out.append((label, float(np.sqrt(np.mean(np.square(values)))), False))
    return out, unit


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
