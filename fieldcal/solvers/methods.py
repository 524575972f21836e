"""The solver a user can ask for; stdlib only, so the command line can offer them cheaply."""
from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from fieldcal.procedure.positions import Procedure

METHODS = ("auto", "powell", "lsq", "classic")
# Whether the solve fits a thermal model beside the calibration (fieldcal.solvers.solve): auto
# when the windows' temperatures span enough to determine it, on whenever they carry one, off never.
THERMAL_MODES = ("auto", "on", "off")


def resolve_method(procedure: Procedure, method: str) -> str:
    """"auto" is classic least squares for an aligned procedure, Powell's norm method otherwise."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    if method == "auto":
        return "classic" if procedure.aligned else "powell"
    return method
