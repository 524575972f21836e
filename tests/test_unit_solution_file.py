"""The parameter file of a unit's solution names the method the run asked for, resolved ("auto":
classic for an aligned procedure, Powell's norm method otherwise), not a mix of its triads'
(solvers/solve.py's UnitSolution.parameter_file)."""
from __future__ import annotations

import numpy as np
import pytest

from fieldcal.calibration import Calibration
from fieldcal.earth import Station
from fieldcal.procedure.positions import parse_procedure
from fieldcal.solvers.solve import UnitSolution


def _triad(name: str, kind: str, unit: str, method: str) -> Calibration:
    return Calibration(name=name, kind=kind, output_unit=unit, method=method, bias=np.zeros(3), K=np.eye(3),
                       sigma=np.full(9, 1e-4), residual_rms=1e-3)


@pytest.mark.parametrize("aligned, asked, written", [(False, "auto", "powell"), (True, "auto", "classic"),
                                                     (False, "lsq", "lsq")])
def test_the_file_names_the_method_asked_for(aligned, asked, written):
    procedure = parse_procedure(f"dwell_s: 10\naligned: {str(aligned).lower()}\npositions:\n"
                                "  - {id: 1, up: z, north: x}\n", "p.yaml")
    unit = UnitSolution(
        solutions={"accelerometer": _triad("accelerometer", "specific_force", "m/s^2", "classic"),
                   "gyroscope": _triad("gyroscope", "angular_rate", "rad/s", "powell")},
        failures={}, problems={}, covariances={},
        inputs={"accelerometer": np.zeros(3), "gyroscope": np.ones(3)})
    pf = unit.parameter_file(procedure, asked, Station(latitude_deg=48.15, height_m=520.0), device_name="unit-7")
    assert pf.provenance.method == written  # not "classic+powell", the triads' own mix
    assert pf.provenance.device_name == "unit-7"
    assert UnitSolution(solutions={}, failures={"gyroscope": "no rate step"}, problems={}, covariances={},
                        inputs={}).parameter_file(procedure, asked, Station(48.15, 520.0)) is None
