"""Per-step averages of a procedure turned into each triad's norm problem.

Specific-force triads use the static dwells only: on the spinning table they also feel the
centripetal acceleration of their offset from the axis. Gyros use the rate steps and the dwells,
each dwell paired with the rate step taken on the same mount.
"""
from __future__ import annotations

import numpy as np

from fieldcal.earth import EARTH_RATE, Station
from fieldcal.model import ANGULAR_RATE, SPECIFIC_FORCE
from fieldcal.procedure.windows import MINUS, PLUS, STATIC, Window
from fieldcal.solvers import CalibrationError, RateNormProblem, StaticNormProblem


def window_indices(windows: list[Window], kind: str) -> list[int]:
    return [i for i, w in enumerate(windows) if w.kind == kind]


def build_problem(name: str, kind: str, output_unit: str, windows: list[Window],
                  means: np.ndarray, station: Station,
                  position_ids) -> tuple[StaticNormProblem | RateNormProblem, list[int]]:
    """The problem for one triad, and the window order of its ``data`` (for covariances)."""
    static = window_indices(windows, STATIC)
    if kind == SPECIFIC_FORCE:
        labels = tuple(f"position {position_ids[windows[i].position]}" for i in static)
        return StaticNormProblem(means[static], station.gravity, name=name, output_unit=output_unit,
                                 labels=labels), static
    if kind != ANGULAR_RATE:
        raise ValueError(f"{name}: unknown triad kind {kind!r}")
    plus, minus = window_indices(windows, PLUS), window_indices(windows, MINUS)
    if not plus:
        raise CalibrationError(f"{name}: the procedure has no rate steps, and a gyro's scale factors "
                               "need them (Earth rate alone is too weak)")
    step_of_position = {windows[i].position: j for j, i in enumerate(plus)}
    if [windows[i].position for i in minus] != [windows[i].position for i in plus]:
        raise ValueError(f"{name}: every +rate step needs a -rate step on the same mount")
    problem = RateNormProblem(
        plus=means[plus], minus=means[minus], table_rate=np.array([windows[i].table_rate for i in plus]),
        static=means[static], static_step=np.array([step_of_position.get(windows[i].position, -1) for i in static],
                                                   dtype=int),
        earth_rate=EARTH_RATE, earth_rate_vertical=station.earth_rate_vertical, name=name,
        output_unit=output_unit,
        step_labels=tuple(f"position {position_ids[windows[i].position]} rate" for i in plus),
        static_labels=tuple(f"position {position_ids[windows[i].position]} static" for i in static))
    return problem, plus + minus + static


def classic_inputs(kind: str, windows: list[Window], up_body: np.ndarray,
                   station: Station) -> tuple[list[int], np.ndarray]:
    """For an aligned procedure: the windows a triad uses and the true input of each (SI).

    Specific force at rest is g along local up; on the table, over whole turns, a gyro sees the
    table rate plus the vertical Earth rate about local up.
    """
    if kind == SPECIFIC_FORCE:
        used = window_indices(windows, STATIC)
        return used, station.gravity * up_body[[windows[i].position for i in used]]
    used = [i for i, w in enumerate(windows) if w.kind in (PLUS, MINUS)]
    rate = np.array([(w.table_rate if w.kind == PLUS else -w.table_rate) + station.earth_rate_vertical
                     for w in (windows[i] for i in used)])
    return used, rate[:, None] * up_body[[windows[i].position for i in used]]
