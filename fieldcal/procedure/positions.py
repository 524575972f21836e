"""Procedure positions: named axis directions turned into fixture attitudes.

A procedure file names, for each position, the local direction each body axis points to
(``up``, ``north``, ``south-up`` for 45° between south and up, ...). From that the attitude
(body -> ENU) and the expected gravity direction in body axes follow.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

PROCEDURES_DIR = Path(__file__).resolve().parents[2] / "procedures"
_WORDS = {"east": (1, 0, 0), "west": (-1, 0, 0), "north": (0, 1, 0), "south": (0, -1, 0),
          "up": (0, 0, 1), "down": (0, 0, -1)}


class ProcedureError(ValueError):
    """A procedure file that cannot be used; the message names the file and field."""


@dataclass(frozen=True)
class Position:
    id: int
    description: str
    attitude: np.ndarray  # body -> ENU; columns are the body axes in ENU

    @property
    def up_body(self) -> np.ndarray:
        """Unit vector of local up (the direction of the specific force at rest) in body axes."""
        return self.attitude[2].copy()


@dataclass(frozen=True)
class RateStep:
    rate_deg_s: float
    turns: int
    ramp_s: float
    settle_s: float


@dataclass(frozen=True)
class Procedure:
    name: str
    title: str
    dwell_s: float
    positions: tuple[Position, ...]
    rate_step: RateStep | None
    aligned: bool = False
    text: str = ""  # the YAML it was read from, for the session capture
    # End each dwell once it holds the information a dwell_s dwell holds at the expected noise
    # (longer when the unit is noisier than its noise model says, shorter when quieter).
    adaptive_dwell: bool = False


def _direction(word: str, where: str) -> np.ndarray:
    parts = str(word).split("-")
    if not parts or any(p not in _WORDS for p in parts) or len(parts) > 2:
        raise ProcedureError(f"{where}: expected a direction like 'up', 'north' or 'south-up', got {word!r}")
    v = np.sum([_WORDS[p] for p in parts], axis=0).astype(float)
    norm = np.linalg.norm(v)
    if norm == 0:
        raise ProcedureError(f"{where}: {word!r} names opposite directions")
    return v / norm


def _position(raw, where: str) -> Position:
    if not isinstance(raw, dict):
        raise ProcedureError(f"{where}: expected a mapping with id, description, axes")
    axes = raw.get("axes")
    if not isinstance(axes, dict) or set(axes) != {"x", "y", "z"}:
        raise ProcedureError(f"{where}.axes: expected a mapping with keys x, y, z")
    cols = [_direction(axes[k], f"{where}.axes.{k}") for k in "xyz"]
    attitude = np.column_stack(cols)
    if not np.allclose(attitude.T @ attitude, np.eye(3), atol=1e-9):
        raise ProcedureError(f"{where}.axes: the axes are not mutually perpendicular")
    if np.linalg.det(attitude) < 0:
        raise ProcedureError(f"{where}.axes: x, y, z form a left-handed set (mirror one horizontal axis)")
    ident = raw.get("id")
    if not isinstance(ident, int):
        raise ProcedureError(f"{where}.id: expected an integer, got {ident!r}")
    return Position(id=ident, description=str(raw.get("description", "")), attitude=attitude)


def _number(raw: dict, key: str, where: str, low: float, high: float, unit: str) -> float:
    """A number in [low, high]; the bounds keep a typo from meaning a run of days."""
    value = raw.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
        raise ProcedureError(f"{where}.{key}: expected a number from {low:g} to {high:g} {unit}, "
                             f"got {value!r}")
    return float(value)


def load_procedure(name_or_path: str | Path) -> Procedure:
    """Load ``procedures/NAME.yaml`` or a path; a bad file gives a one-line ProcedureError."""
    path = Path(name_or_path)
    if not path.suffix:
        path = PROCEDURES_DIR / f"{name_or_path}.yaml"
    try:
        text = path.read_text()
    except OSError as exc:
        raise ProcedureError(f"{path}: cannot read procedure ({exc.strerror})") from None
    return parse_procedure(text, path.name)


def parse_procedure(text: str, where: str) -> Procedure:
    """A procedure from its YAML text; ``where`` names it in errors."""
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ProcedureError(f"{where}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(raw, dict):
        raise ProcedureError(f"{where}: expected a mapping at the top level")
    positions = raw.get("positions")
    if not isinstance(positions, list) or not positions:
        raise ProcedureError(f"{where}.positions: expected a non-empty list")
    parsed = tuple(_position(p, f"{where}.positions[{i}]") for i, p in enumerate(positions))
    step = raw.get("rate_step")
    rate_step = None
    if step is not None:
        if not isinstance(step, dict):
            raise ProcedureError(f"{where}.rate_step: expected a mapping")
        turns = step.get("turns")
        if isinstance(turns, bool) or not isinstance(turns, int) or not 1 <= turns <= 100:
            raise ProcedureError(f"{where}.rate_step.turns: expected a whole number from 1 to 100, "
                                 f"got {turns!r}")
        here = f"{where}.rate_step"
        # Single-axis field tables run 0.1-20 °/s (paper section 4); allow up to gyro full scale.
        rate_step = RateStep(_number(step, "rate_deg_s", here, 0.1, 400, "°/s"), turns,
                             _number(step, "ramp_s", here, 0, 600, "s"),
                             _number(step, "settle_s", here, 0, 600, "s"))
    adaptive = raw.get("adaptive_dwell", False)
    if not isinstance(adaptive, bool):
        raise ProcedureError(f"{where}.adaptive_dwell: expected true or false, got {adaptive!r}")
    return Procedure(name=str(raw.get("name", Path(where).stem)), title=str(raw.get("title", "")),
                     dwell_s=_number(raw, "dwell_s", where, 1, 86400, "s"), positions=parsed,
                     rate_step=rate_step, aligned=bool(raw.get("aligned", False)), text=text,
                     adaptive_dwell=adaptive)
