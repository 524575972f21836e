"""Each position's residual of a solved triad, in the operator's units, and lists of positions:
what the results screen and the certificate show."""
from __future__ import annotations

import re

import numpy as np

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
        return [(f"avg {i + 1}", float(r), False)
                for i, r in enumerate(np.sqrt(np.mean(rows**2, axis=1)))], unit
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


def position_list(ids: list[int]) -> str:
    """1, 4, 7–9: consecutive ids as a range."""
    runs: list[list[int]] = []
    for i in ids:
        if runs and i == runs[-1][-1] + 1:
            runs[-1].append(i)
        else:
            runs.append([i])
    return ", ".join(f"{r[0]}–{r[-1]}" if len(r) > 2 else ", ".join(map(str, r)) for r in runs)


def positions_phrase(ids: list[int]) -> str:
    """"position 3", "positions 1, 4–6"."""
    return f"position{'s' if len(ids) > 1 else ''} {position_list(ids)}"
