"""The cube's orientation as a small top view: which body axis points where (no Textual here).

Seen from above, north at the top: a body axis lying (mostly) horizontal is drawn as an arrow
toward its compass side, ``⊙`` marks an axis pointing up (towards you) and ``⊗`` one pointing
down; an axis tilted 45° shows both, e.g. ``↓x⊙`` is x pointing south and up.
"""
from __future__ import annotations

import numpy as np

from fieldcal.procedure.positions import Position

_AXES = "xyz"
_SLOT = 3


def _label(axis: str, v: np.ndarray) -> tuple[str, str]:
    """(slot, label) for a body axis with ENU direction v."""
    east, north, up = (float(c) for c in v)
    horizontal = np.hypot(east, north)
    vertical = "⊙" if up > 0.3 else "⊗" if up < -0.3 else ""
    if horizontal < 0.3:
        return "centre", f"{vertical}{axis}"
    if abs(north) >= abs(east):
        slot, arrow = ("N", "↑") if north > 0 else ("S", "↓")
        return slot, f"{arrow}{axis}{vertical}"
    if east > 0:
        return "E", f"{axis}→{vertical}"
    return "W", f"←{axis}{vertical}"


def top_view(position: Position, large: bool = False) -> list[str]:
    """Seven lines, 20 cells wide (``large``: eleven lines, 32 wide): the cube from above with
    its axes, compass and legend."""
    slots: dict[str, list[str]] = {"N": [], "S": [], "E": [], "W": [], "centre": []}
    for i, axis in enumerate(_AXES):
        slot, label = _label(axis, position.attitude[:, i])
        slots[slot].append(label)
    s = {k: ",".join(v) or "·" for k, v in slots.items()}
    if large:
        blank = f"  │{' ' * 25}│"
        return [
            f"{'N':>15}",
            f"  ┌{'─' * 25}┐",
            blank,
            f"  │{s['N']:^25}│",
            blank,
            f"W │ {s['W']:<{_SLOT}}{s['centre']:^17}{s['E']:>{_SLOT}} │ E",
            blank,
            f"  │{s['S']:^25}│",
            blank,
            f"  └{'─' * 25}┘",
            f"{'S':>15}     ⊙up ⊗down",
        ]
    return [
        "        N",
        "  ┌─────────────┐",
        f"  │    {s['N']:^{_SLOT + 2}}    │",
        f"W │ {s['W']:<{_SLOT}} {s['centre']:^{_SLOT}} {s['E']:>{_SLOT}} │ E",
        f"  │    {s['S']:^{_SLOT + 2}}    │",
        "  └─────────────┘",
        "        S  ⊙up ⊗down",
    ]
