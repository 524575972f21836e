"""A window of samples the solvers average: a still dwell or a constant-rate turn of a position.

Its own module (stdlib only) because the engine, the solvers and the simulated run all name it,
and the engine and solvers must not import the simulator.
"""
from __future__ import annotations

from dataclasses import dataclass

STATIC, PLUS, MINUS = "static", "plus", "minus"


@dataclass(frozen=True)
class Window:
    kind: str  # STATIC, PLUS or MINUS
    position: int  # index into the procedure's positions
    start: float  # s, sample time
    duration: float  # s
    table_rate: float = 0.0  # rad/s, magnitude
