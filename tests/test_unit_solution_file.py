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


def test_the_averages_covariance_adds_each_windows_quantisation_to_its_noise():
    """By hand: white noise 0.1 per √Hz gives a 2 s and a 4 s window a variance of 0.01/2 and
    0.01/4 per axis, times K Kᵀ = 4 I: 0.02 and 0.01; a step of 0.06 adds 0.06²/12 = 3e-4 per
    sample, over 200 and 400 samples at 100 Hz: 1.5e-6 and 7.5e-7. Nothing across windows or axes."""
    from fieldcal.procedure.windows import STATIC, Window
    from fieldcal.solvers.solve import TriadModel, average_covariance
    from drivers.noise import TriadNoise

    windows = [Window(STATIC, 0, 0.0, 2.0), Window(STATIC, 1, 10.0, 4.0)]
    model = TriadModel("specific_force", "m/s^2", TriadNoise(white=0.1), 2.0 * np.eye(3), lsb=0.06)
    expected = np.diag([0.02 + 1.5e-6] * 3 + [0.01 + 7.5e-7] * 3)
    np.testing.assert_allclose(average_covariance(model, windows, 100.0), expected, rtol=1e-12, atol=1e-18)
    without = TriadModel("specific_force", "m/s^2", TriadNoise(white=0.1), 2.0 * np.eye(3))
    np.testing.assert_allclose(average_covariance(without, windows, 100.0), np.diag([0.02] * 3 + [0.01] * 3),
                               rtol=1e-12, atol=1e-18)
