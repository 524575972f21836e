"""Operator units at the edges: SI inside, mg, °/h, ppm and mrad on screens and in tables.

A triad reports in its output unit: a physical one (m/s², g, deg/s, ...) or the device's own
(counts, mV). Biases are shown in mg (accelerometers, inclinometers) or °/h (gyros) whenever the
output unit is physical; scale factors as a dimensionless factor (1 + error, its σ in ppm) when
it is physical, else in the device's unit per g or per °/s (count/g, as data sheets give it);
angles in mrad.
"""
from __future__ import annotations

import math

from fieldcal.model import ANGULAR_RATE, SPECIFIC_FORCE

STANDARD_GRAVITY = 9.80665  # m/s² per g
_DEG = math.pi / 180  # rad per degree

# SI (m/s², rad/s) per output unit, for the output units that are physical.
SI_PER_UNIT = {
    SPECIFIC_FORCE: {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "g": STANDARD_GRAVITY,
                     "mg": STANDARD_GRAVITY * 1e-3, "ug": STANDARD_GRAVITY * 1e-6},
    ANGULAR_RATE: {"rad/s": 1.0, "mrad/s": 1e-3, "deg/s": _DEG, "°/s": _DEG, "dps": _DEG,
                   "mdeg/s": _DEG * 1e-3, "deg/h": _DEG / 3600, "°/h": _DEG / 3600},
}
# The operator's unit for a bias of each kind, and SI per that unit.
_BIAS_UNIT = {SPECIFIC_FORCE: ("mg", STANDARD_GRAVITY * 1e-3), ANGULAR_RATE: ("°/h", _DEG / 3600)}
# A device-unit scale factor is shown per g or per °/s, as data sheets give sensitivities.
_PER_UNIT = {SPECIFIC_FORCE: ("g", STANDARD_GRAVITY), ANGULAR_RATE: ("°/s", _DEG)}

BIAS, SCALE, ANGLE = "bias", "scale", "angle"
DIMENSIONLESS = "1"


def group_of(parameter: str) -> str:
    """bias_x -> BIAS, scale_y -> SCALE, delta_yz / m_xy -> ANGLE."""
    if parameter.startswith("bias"):
        return BIAS
    return SCALE if parameter.startswith("scale") else ANGLE


def operator_unit(kind: str, output_unit: str, group: str) -> tuple[float, str]:
    """(factor, unit): a parameter of ``group`` in ``output_unit``-based solver units, times
    factor, is in the operator's unit."""
    si = SI_PER_UNIT[kind].get(output_unit)
    if group == BIAS:  # output units; a residual in output or SI units is shown the same way
        if si is None:
            return 1.0, output_unit
        unit, si_per = _BIAS_UNIT[kind]
        return si / si_per, unit
    if group == SCALE:  # output units per SI unit
        if si is not None:
            return si, DIMENSIONLESS
        per, si_per = _PER_UNIT[kind]
        return si_per, f"{output_unit}/({per})" if "/" in per else f"{output_unit}/{per}"
    if group == ANGLE:
        return 1e3, "mrad"
    raise ValueError(f"unknown parameter group {group!r}")


_GROUP_BY_INDEX = (BIAS,) * 3 + (SCALE,) * 3


def display_scale(kind: str, output_unit: str, index: int) -> float:
    """Factor from the solver's unit of parameter ``index`` (PARAM_NAMES order) to the operator's."""
    return operator_unit(kind, output_unit, _GROUP_BY_INDEX[index] if index < 6 else ANGLE)[0]


def param_unit(kind: str, output_unit: str, index: int) -> str:
    return operator_unit(kind, output_unit, _GROUP_BY_INDEX[index] if index < 6 else ANGLE)[1]
