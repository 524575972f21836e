"""Procedure positions: named axis directions turned into fixture attitudes.

A procedure file names, for each position, the local direction each body axis points to
(``up``, ``north``, ``south-up`` for 45° between south and up, ...). From that the attitude
(body -> ENU) and the expected gravity direction in body axes follow.

Or, the other way round, which body direction points up and which one's horizontal part points
north: ``up: x+y+z, north: x`` is the unit on a corner (gravity along the body diagonal, every
axis 35° above the horizontal, x's horizontal part towards north), which compass words cannot
say. A body direction is a signed sum of distinct axes: ``z``, ``-x``, ``x-y``, ``-x+y-z``.
"""
from __future__ import annotations

from dataclasses import dataclass
import re
from pathlib import Path

import numpy as np

from fieldcal.paths import PROCEDURES_DIR, find_named, not_found  # noqa: F401 (PROCEDURES_DIR: imported from here)
from fieldcal.validation import FieldReader, describe, join, line_of, parse_yaml, read_yaml_text

_WORDS = {"east": (1, 0, 0), "west": (-1, 0, 0), "north": (0, 1, 0), "south": (0, -1, 0),
          "up": (0, 0, 1), "down": (0, 0, -1)}


class ProcedureError(ValueError):
    """A procedure file that cannot be used; the message names the file and field."""

    def __init__(self, message: str, path: str = "", field: str = ""):
        super().__init__(message)
        self.path, self.field = path, field


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
    # A planned procedure's (``fieldcal plan``) σ per parameter, (triad, parameter, σ in the
    # operator units `fieldcal plan` prints), shown against the σ reached while it runs.
    targets: tuple[tuple[str, str, float], ...] = ()
    # Each position's own rate step (None: static only), when a position gives one (``rate_step:
    # none`` or ``{rate_deg_s, turns}``); empty: every position takes ``rate_step``.
    position_steps: tuple[RateStep | None, ...] = ()
    # The operator places the positions in any order: the engine recognises which remaining one
    # the unit is in from gravity and starts its dwell once the unit is still, with no "ready".
    any_order: bool = False

    def rate_step_at(self, index: int) -> RateStep | None:
        """The rate step of the position at ``index`` (None: a static dwell only)."""
        return self.position_steps[index] if self.position_steps else self.rate_step

    @property
    def rate_steps(self) -> tuple[RateStep, ...]:
        """The distinct rate steps the procedure makes, slowest first (empty: static only)."""
        steps = self.position_steps if self.position_steps else (self.rate_step,)
        return tuple(sorted({s for s in steps if s is not None}, key=lambda s: (s.rate_deg_s, s.turns)))


# A procedure's name becomes part of a session directory's name: a plain file name, so that
# "../../x" cannot write outside --out and a 300-character name cannot hit the file system's limit.
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
_TEXT_LIMIT = 200  # characters of a title or description shown to the operator


def _direction(r: FieldReader, word, where: str, line: int | None) -> np.ndarray:
    parts = word.split("-") if isinstance(word, str) else []
    if not parts or any(p not in _WORDS for p in parts) or len(parts) > 2:
        r.fail(where, "a direction like 'up', 'north' or 'south-up'", describe(word), line)
    v = np.sum([_WORDS[p] for p in parts], axis=0).astype(float)
    norm = np.linalg.norm(v)
    if norm == 0:
        r.refuse(where, f"{word!r} names opposite directions", line)
    return v / norm


_BODY_DIRECTION = re.compile(r"[+-]?[xyz](?:[+-][xyz]){0,2}")


def _body_direction(r: FieldReader, word, where: str, line: int | None) -> np.ndarray:
    """A signed sum of distinct body axes ('x+y+z', '-z', 'x-y'), normalised."""
    if not isinstance(word, str) or not _BODY_DIRECTION.fullmatch(word) \
            or len(set(re.findall("[xyz]", word))) != len(re.findall("[xyz]", word)):
        r.fail(where, "a body direction like 'z', '-x', 'x-y' or 'x+y+z' (each axis at most once)",
               describe(word), line)
    v = np.zeros(3)
    for sign, axis in re.findall(r"([+-]?)([xyz])", word):
        v["xyz".index(axis)] = -1.0 if sign == "-" else 1.0
    return v / np.linalg.norm(v)


def _attitude_from_up_and_north(r: FieldReader, m: dict, where: str) -> np.ndarray:
    """Body -> ENU from the body direction that points up and the one whose horizontal part
    points north."""
    up = _body_direction(r, m["up"], join(where, "up"), line_of(m, "up"))
    toward_north = _body_direction(r, m["north"], join(where, "north"), line_of(m, "north"))
    attitude = attitude_from_up_and_north(up, toward_north)
    if attitude is None:
        r.refuse(join(where, "north"), f"{m['north']!r} is along up ({m['up']!r}), so it has no horizontal "
                 "part to point north; name another body direction", line_of(m, "north"))
    return attitude


def attitude_from_up_and_north(up: np.ndarray, toward_north: np.ndarray) -> np.ndarray | None:
    """Body -> ENU whose local up is ``up`` (body axes) and whose north is the horizontal part of
    ``toward_north``; None when that has (almost) none."""
    up = up / np.linalg.norm(up)
    north = toward_north / np.linalg.norm(toward_north)
    north = north - (north @ up) * up
    if np.linalg.norm(north) < 0.1:
        return None
    north /= np.linalg.norm(north)
    return np.array([np.cross(north, up), north, up])  # rows east, north, up: east = north × up


def _text(r: FieldReader, m: dict, key: str, where: str) -> str:
    """Optional free text, checked before any conversion (a list is not a title)."""
    if key not in m:
        return ""
    value = m[key]
    if not isinstance(value, str) or len(value) > _TEXT_LIMIT:
        r.fail(join(where, key), f"text of at most {_TEXT_LIMIT} characters", describe(value),
               line_of(m, key))
    return value


def _rate_step(r: FieldReader, raw, where: str, line: int | None, default: RateStep | None) -> RateStep:
    """``{rate_deg_s, turns, ramp_s, settle_s}``; at a position, ramp_s and settle_s may be left to
    the procedure's own rate step."""
    inherit = ("ramp_s", "settle_s") if default is not None else ()
    needed = ("rate_deg_s", "turns") + tuple(k for k in ("ramp_s", "settle_s") if k not in inherit)
    step = r.mapping(raw, where, needed, inherit, line=line)

    def seconds(key):
        return r.bounded(step, key, where, 0, 600, "s") if key in step else getattr(default, key)

    # Single-axis field tables run 0.1-20 °/s (paper section 4); allow up to gyro full scale.
    return RateStep(r.bounded(step, "rate_deg_s", where, 0.1, 400, "°/s"), r.whole(step, "turns", where, 1, 100),
                    seconds("ramp_s"), seconds("settle_s"))


def _position_step(r: FieldReader, raw, where: str, default: RateStep | None):
    """A position's ``rate_step``: ``none`` (a static dwell only) or its own step."""
    if not isinstance(raw, dict) or "rate_step" not in raw:
        return default
    value, line = raw["rate_step"], line_of(raw, "rate_step")
    if value == "none":
        return None
    if not isinstance(value, dict):
        r.fail(join(where, "rate_step"), "'none' or a mapping {rate_deg_s, turns"
               + ("}" if default is not None else ", ramp_s, settle_s}"), describe(value), line)
    return _rate_step(r, value, join(where, "rate_step"), line, default)


def _position(r: FieldReader, raw, where: str) -> Position:
    m = r.mapping(raw, where, ("id",), ("axes", "up", "north", "description", "rate_step"))
    by_up = [k for k in ("up", "north") if k in m]
    if "axes" in m and by_up:
        r.refuse(join(where, by_up[0]), "give either axes or up and north, not both", line_of(m, by_up[0]))
    if "axes" not in m and len(by_up) < 2:
        missing = "axes, or up and north" if not by_up else "north" if "up" in m else "up"
        r.refuse(join(where, "north" if "up" in m else "up") if by_up else join(where, "axes"),
                 f"missing ({missing})", line_of(m))
    if by_up:
        attitude = _attitude_from_up_and_north(r, m, where)
    else:
        axes = r.mapping(m["axes"], join(where, "axes"), ("x", "y", "z"), line=line_of(m, "axes"))
        cols = [_direction(r, axes[k], f"{where}.axes.{k}", line_of(axes, k)) for k in "xyz"]
        attitude = np.column_stack(cols)
        if not np.allclose(attitude.T @ attitude, np.eye(3), atol=1e-9):
            r.refuse(f"{where}.axes", "the axes are not mutually perpendicular", line_of(m, "axes"))
        if np.linalg.det(attitude) < 0:
            r.refuse(f"{where}.axes", "x, y, z form a left-handed set (mirror one horizontal axis)",
                     line_of(m, "axes"))
    ident = r.whole(m, "id", where, 0, 10**6)
    return Position(id=ident, description=_text(r, m, "description", where), attitude=attitude)


def load_procedure(name_or_path: str | Path) -> Procedure:
    """Load a path, or a bare name: NAME.yaml here, else the shipped one (``fieldcal.paths``); a bad
    file gives a one-line ProcedureError."""
    path = Path(name_or_path)
    if not path.suffix and not path.exists():
        found = find_named(path, "procedure")
        if found is None:
            raise ProcedureError(not_found(path, "procedure"), str(name_or_path))
        path = found
    return parse_procedure(read_yaml_text(path, ProcedureError, "procedure"), str(path))


def parse_procedure(text: str, where: str) -> Procedure:
    """A procedure from its YAML text; ``where`` names it in errors."""
    raw = parse_yaml(text, where, ProcedureError)
    r = FieldReader(where, ProcedureError)
    m = r.mapping(raw, "", ("dwell_s", "positions"), ("name", "title", "rate_step", "aligned", "adaptive_dwell",
                                                        "targets", "any_order"),
                  what="a procedure: a mapping")
    positions = m["positions"]
    if not isinstance(positions, list) or not positions:
        r.fail("positions", "a non-empty list", describe(positions), line_of(m, "positions"))
    parsed = tuple(_position(r, p, f"positions[{i}]") for i, p in enumerate(positions))
    rate_step = None
    if m.get("rate_step") is not None:
        rate_step = _rate_step(r, m["rate_step"], "rate_step", line_of(m, "rate_step"), None)
    position_steps = tuple(_position_step(r, p, f"positions[{i}]", rate_step) for i, p in enumerate(positions))
    if all(step == rate_step for step in position_steps):
        position_steps = ()  # every position as the procedure: the plain form
    name = r.string(m, "name", "") if "name" in m else Path(where).stem
    if not NAME_PATTERN.fullmatch(name):
        r.fail("name", "a plain file name: up to 64 letters, digits, '.', '_' or '-', not "
               "starting with '.' (it names the session directory)", describe(name),
               line_of(m, "name"))
    return Procedure(name=name, title=_text(r, m, "title", ""),
                     dwell_s=r.bounded(m, "dwell_s", "", 1, 86400, "s"), positions=parsed,
                     rate_step=rate_step, aligned=r.boolean(m, "aligned", "", False), text=text,
                     adaptive_dwell=r.boolean(m, "adaptive_dwell", "", False), targets=_targets(r, m),
                     position_steps=position_steps, any_order=r.boolean(m, "any_order", "", False))


def _targets(r: FieldReader, m: dict) -> tuple[tuple[str, str, float], ...]:
    """``targets: {TRIAD: {PARAMETER: σ, ...}, ...}``, every σ a number > 0."""
    from fieldcal.model import PARAM_NAMES

    if m.get("targets") is None:
        return ()
    raw = m["targets"]
    if not isinstance(raw, dict) or not all(isinstance(k, str) for k in raw):
        r.fail("targets", "a mapping of triad names to {parameter: σ}", describe(raw), line_of(m, "targets"))
    out = []
    for triad, body in raw.items():
        where = join("targets", triad)
        params = r.mapping(body, where, (), PARAM_NAMES, line=line_of(raw, triad))
        for name, value in params.items():
            sigma = r.value(value, join(where, name), 0.0, line_of(params, name))
            if sigma <= 0:
                r.fail(join(where, name), "a σ > 0", describe(value), line_of(params, name))
            out.append((triad, name, sigma))
    return tuple(out)


_SIGNED_SUMS = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)
                         if (a, b, c) != (0, 0, 0)], dtype=float)


def body_direction_name(v, tolerance_deg: float = 10.0) -> str | None:
    """``v`` (body axes) as the procedure format writes a body direction: '-x' for an axis,
    'x+z' for a face diagonal, '-x-y-z' for a body diagonal (within ``tolerance_deg``); None
    when it is none of these."""
    v = np.asarray(v, dtype=float) / np.linalg.norm(v)
    units = _SIGNED_SUMS / np.linalg.norm(_SIGNED_SUMS, axis=1, keepdims=True)
    best = int(np.argmax(units @ v))
    if np.degrees(np.arccos(np.clip(units[best] @ v, -1.0, 1.0))) > tolerance_deg:
        return None
    name = "".join(("-" if s < 0 else "+") + a for s, a in zip(_SIGNED_SUMS[best], "xyz") if s)
    return name.removeprefix("+")


def compass_side(v_enu) -> str:
    """The compass side the horizontal part of an ENU vector points to: 'north', 'south-east'."""
    east, north = np.asarray(v_enu, dtype=float)[:2] / max(float(np.hypot(v_enu[0], v_enu[1])), 1e-12)
    return "-".join(w for c, w in ((north, "north" if north > 0 else "south"),
                                   (east, "east" if east > 0 else "west")) if abs(c) > 0.3)


def position_words(p: Position) -> str:
    """The position's description, or, when its file gives none, its attitude in the words of the
    procedure files: 'z-upward, x-north, y-west' on a face, 'x+y+z upward, x towards north' on a
    corner (the body direction that points up, and where the axes' horizontal parts point)."""
    if p.description:
        return p.description
    up = body_direction_name(p.up_body)
    if up is None:
        words = ["(" + ", ".join(f"{c:.2f}" for c in p.up_body) + ") upward"]
    elif len(up.lstrip("-")) == 1:  # a face: the files' own 'z-upward', 'x-downward'
        words = [f"{up[-1]}-{'downward' if up.startswith('-') else 'upward'}"]
    else:
        words = [f"{up} upward"]
    level = [i for i in range(3) if abs(p.attitude[2, i]) < 0.1]
    if level:
        words += [f"{'xyz'[i]}-{compass_side(p.attitude[:, i])}" for i in level]
    else:
        i = int(np.argmin(np.abs(p.attitude[2])))  # the axis nearest the horizontal
        words.append(f"{'xyz'[i]} towards {compass_side(p.attitude[:, i])}")
    return ", ".join(words)
