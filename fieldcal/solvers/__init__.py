"""Pure solvers: per-position averages in, a ``fieldcal.calibration.Calibration`` out.

The names below load their module (and scipy.optimize) on first use, so importing a light
submodule such as ``fieldcal.solvers.methods`` does not pay for the solvers.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what the names below are, for static tools (at run time: loaded on first use)
    from fieldcal.solvers.classic import solve_classic
    from fieldcal.solvers.norm import CalibrationError, solve_norm
    from fieldcal.solvers.problems import RateNormProblem, StaticNormProblem

_HOMES = {
    "solve_classic": "classic", "CalibrationError": "norm", "solve_norm": "norm",
    "RateNormProblem": "problems", "StaticNormProblem": "problems",
}

__all__ = ["CalibrationError", "RateNormProblem", "StaticNormProblem", "solve_classic", "solve_norm"]  # _HOMES' keys, spelt out for static tools


def __getattr__(name: str):
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOMES[name]}"), name)
    globals()[name] = value
    return value
