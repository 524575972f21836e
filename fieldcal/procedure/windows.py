"""What a procedure averages: windows (static, +ω, −ω) and the records of completed steps.

``Window`` is what the solvers take (where a window lies in sample time, at which table rate);
``WindowRecord`` and ``StepRecord`` are what the engine keeps per completed step and what a
session's ``step`` documents hold, with ``to_dict``/``from_dict`` for the JSON that is stored.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class WindowKind(StrEnum):
    STATIC = "static"
    PLUS = "plus"  # the table turning at +ω
    MINUS = "minus"  # at −ω


STATIC, PLUS, MINUS = WindowKind.STATIC, WindowKind.PLUS, WindowKind.MINUS


@dataclass(frozen=True)
class Window:
    kind: WindowKind
    position: int  # index into the procedure's positions
    start: float  # s, sample time
    duration: float  # s
    table_rate: float = 0.0  # rad/s, magnitude
    temperature_c: float | None = None  # the unit's mean temperature over it, when measured


@dataclass(frozen=True)
class WindowRecord:
    """One averaged window of a completed step, as the engine measured it."""

    kind: WindowKind
    start: float  # s, sample time of the first averaged sample
    duration: float  # s of averaged samples
    rate_deg_s: float  # commanded table rate (signed; 0 for static)
    means: dict[str, list[float]]  # triad -> mean output over the window
    # The unit's mean temperature over the window, °C (the thermal fit's abscissa); None when
    # the device reports none, and in every session written before temperatures were kept.
    temperature_c: float | None = None

    def to_dict(self) -> dict:
        said = {"temperature_c": self.temperature_c} if self.temperature_c is not None else {}
        return {"kind": str(self.kind), "start": self.start, "duration": self.duration,
                "rate_deg_s": self.rate_deg_s, "means": {n: list(v) for n, v in self.means.items()}, **said}

    @classmethod
    def from_dict(cls, doc: dict) -> WindowRecord:
        return cls(WindowKind(doc["kind"]), float(doc["start"]), float(doc["duration"]),
                   float(doc["rate_deg_s"]), {n: list(v) for n, v in doc["means"].items()},
                   None if doc.get("temperature_c") is None else float(doc["temperature_c"]))

    @property
    def end(self) -> float:
        return self.start + self.duration


@dataclass(frozen=True)
class StepRecord:
    """A completed step: which position, and its windows in the order they were measured."""

    step: int  # 0-based index into the procedure's positions
    position_id: int
    windows: tuple[WindowRecord, ...]

    def to_dict(self) -> dict:
        return {"step": self.step, "position_id": self.position_id,
                "windows": [w.to_dict() for w in self.windows]}

    @classmethod
    def from_dict(cls, doc: dict) -> StepRecord:
        return cls(int(doc["step"]), int(doc["position_id"]),
                   tuple(WindowRecord.from_dict(w) for w in doc["windows"]))
