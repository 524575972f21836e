"""What the operator must do to the unit, in the operator's words (no Textual here).

``placement(previous, target)`` says how to get from one position to the next: "turn it over:
z must point down, x north", "rotate it 90° about the vertical so that x points north". A move
that changes only the heading is flagged: gravity, which the orientation check measures, is
the same before and after, so a heading mistake would pass unseen.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fieldcal.procedure.positions import Position, compass_side

_AXES = "xyz"
_ENU = (("east", "west"), ("north", "south"), ("up", "down"))


@dataclass(frozen=True)
class Guidance:
    text: str
    heading_only: bool = False  # the up direction stays: the orientation check cannot see it


def direction_word(v) -> str:
    """An ENU direction as the procedure files name it: north, south-up, east."""
    words = [pos if c > 0 else neg for c, (pos, neg) in zip(v, _ENU) if abs(c) > 0.3]
    return "-".join(words)


def _vertical_axis(p: Position) -> tuple[str, str] | None:
    """(axis, "up"/"down") of the body axis that is vertical in ``p``, if one is."""
    i = int(np.argmax(np.abs(p.attitude[2])))
    if abs(p.attitude[2, i]) < 0.9:
        return None
    return _AXES[i], "up" if p.attitude[2, i] > 0 else "down"


def _horizontal_axis(p: Position) -> tuple[str, str] | None:
    """(axis, compass word) of the first body axis lying level in ``p``, if one does."""
    for i, axis in enumerate(_AXES):
        if abs(p.attitude[2, i]) < 0.1:
            return axis, direction_word(p.attitude[:, i])
    return None


def _elevations(p: Position) -> str:
    """Each body axis's angle above (or below) the horizontal and the compass side its horizontal
    part points to: 'x 35° up towards north, y 35° up towards south-east, ...'."""
    out = []
    for i, axis in enumerate(_AXES):
        v = p.attitude[:, i]
        elevation = math.degrees(math.asin(float(np.clip(v[2], -1.0, 1.0))))
        compass = compass_side(v)
        out.append(f"{axis} {abs(elevation):.0f}° {'up' if elevation > 0 else 'down'} towards {compass}")
    return ", ".join(out)


def _heading_change_deg(previous: Position, target: Position) -> float:
    """The turn about the vertical from one pose to the other, counter-clockwise seen from
    above positive (degrees, -180..180)."""
    r = target.attitude @ previous.attitude.T  # ENU -> ENU: old body axes onto new ones
    return math.degrees(math.atan2(r[1, 0], r[0, 0]))


COMPASS = ("north", "south", "east", "west")


def names_heading(description: str) -> bool:
    """Does a position's description say where its level axes point (a compass word)?"""
    return any(word in description.lower() for word in COMPASS)


def placement(previous: Position | None, target: Position) -> Guidance:
    """How to move the unit from ``previous`` (None: not placed yet) into ``target``."""
    vertical, level = _vertical_axis(target), _horizontal_axis(target)
    if previous is None:  # a position the file does not describe: its attitude says it
        if target.description and names_heading(target.description):
            return Guidance(f"place it {target.description}")
        # (a planned position's "y-down" says which face is down, not where the others point)
        return _pose("place it", "on", target, vertical, level)
    cos = float(np.clip(previous.up_body @ target.up_body, -1.0, 1.0))
    tip = math.degrees(math.acos(cos))
    if tip < 5.0:
        turn = _heading_change_deg(previous, target)
        if abs(turn) < 5.0:
            return Guidance("leave it as it is", heading_only=True)
        sense = " about the vertical" if abs(abs(turn) - 180) < 5 else \
            (" anticlockwise" if turn > 0 else " clockwise") + " (seen from above)"
        where = f" so that {level[0]} points {level[1]}" if level else ""
        return Guidance(f"rotate it {abs(turn):.0f}°{sense}{where}", heading_only=True)
    verb = "turn it over" if tip > 135 else f"tip it {tip:.0f}° over"
    return _pose(verb, "onto", target, vertical, level)


def _pose(verb: str, onto: str, target: Position, vertical, level) -> Guidance:
    """``verb`` followed by the pose ``target`` puts the unit in, axis by axis."""
    if vertical is None and level is None:  # on a corner: no compass word is an axis's direction
        return Guidance(f"{verb} {onto} a corner: {_elevations(target)}")
    if vertical is None:  # tilted: every axis's direction, as the procedure file gives them
        words = [f"{a} {direction_word(target.attitude[:, i])}" for i, a in enumerate(_AXES)]
        if level is not None:
            words.sort(key=lambda w: not w.startswith(level[0]))
        return Guidance(f"{verb}: {', '.join(words)}")
    then = f", {level[0]} {level[1]}" if level else ""
    return Guidance(f"{verb}: {vertical[0]} must point {vertical[1]}{then}")
