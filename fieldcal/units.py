"""Operator units at the edges: SI inside, mg, °/h, ppm and mrad on screens and in tables."""
from __future__ import annotations

import math

from fieldcal.model import ANGULAR_RATE

STANDARD_GRAVITY = 9.80665  # m/s² per g
_SI_OUTPUT = {"m/s^2", "rad/s"}


def display_scale(kind: str, output_unit: str, index: int) -> float:
    """Factor from the solver's unit of parameter ``index`` to the operator's unit."""
    if index < 3:  # bias, in output units
        if output_unit not in _SI_OUTPUT:
            return 1.0
        return 3600 * 180 / math.pi if kind == ANGULAR_RATE else 1e3 / STANDARD_GRAVITY
    if index < 6:  # scale factor k, output units per SI unit
        return 1.0
    return 1e3  # rad -> mrad


def param_unit(kind: str, output_unit: str, index: int) -> str:
    if index < 3:
        if output_unit not in _SI_OUTPUT:
            return output_unit
        return "°/h" if kind == ANGULAR_RATE else "mg"
    if index < 6:
        si = "rad/s" if kind == ANGULAR_RATE else "m/s^2"
        return "1" if output_unit in _SI_OUTPUT else f"{output_unit}/({si})"
    return "mrad"
